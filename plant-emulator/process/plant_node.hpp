// The pmsm-plant process's bus side: one Plant on one CAN bus endpoint, in lockstep or in
// real time (DESIGN §5), speaking the one protocol of hal/ (DESIGN §6).
//
// Lockstep: the plant sends sample k and waits for the INVERTER_COMMAND computed from it
// (sequence k); only then does it step, so simulated time advances with commands alone and
// the same configuration plus the same command stream give the same samples. While no such
// command comes it re-sends sample k every resend_interval of wall-clock time, so that a
// controller started later can lock on. Commands with another sequence are counted (stale,
// duplicate, future) and ignored.
//
// Real time: the plant runs on its own clock (absolute deadlines, one PWM period each). At
// every boundary it steps with the command received for that period; without one it holds
// the last command and counts the period as missing, and a command that comes after its
// period is counted late. After command_timeout without a valid, fresh command it turns the
// gates off (safe torque off: enable = false) and counts the timeout; it switches them on
// again when commands return.
//
// Both modes publish TRUTH_THERMAL, TRUTH_ELECTRICAL and PLANT_STATUS every truth_period of
// simulated time.
//
// The per-period path allocates nothing, logs nothing and takes no lock: counters are
// atomics written by the run() thread alone, read by anyone through stats(), and a normal
// thread turns them into log lines (see main.cpp).
#pragma once

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <optional>
#include <vector>

#include "pmsm/hal/can_bus.hpp"
#include "pmsm/hal/codec.hpp"
#include "pmsm/hal/counters.hpp"
#include "pmsm/hal/protocol.hpp"
#include "pmsm/plant/config.hpp"
#include "pmsm/plant/plant.hpp"

namespace pmsm::plant {

enum class RunMode : std::uint8_t { kLockstep, kRealtime };

[[nodiscard]] const char* to_string(RunMode mode) noexcept;

// The truth's publication interval in whole PWM periods, at least one: the given period over
// the plant's, rounded (pmsm-plant --check prints what this gives).
[[nodiscard]] std::uint64_t truth_every_periods(std::chrono::nanoseconds truth_period, double period_s);

struct PlantNodeOptions {
  hal::protocol::NodeId node = 0;
  RunMode mode = RunMode::kLockstep;
  // Simulated time between two publications of the bench frames (truth and status).
  std::chrono::nanoseconds truth_period{std::chrono::milliseconds{100}};
  // Real time only: wall-clock time without a valid, fresh command before the gates go off.
  std::chrono::nanoseconds command_timeout{std::chrono::milliseconds{5}};
  // Simulated time after which run() returns; none: until stop is requested.
  std::optional<double> duration_s;
  // Lockstep only: wall-clock time between re-sends of a sample nobody has answered.
  std::chrono::nanoseconds resend_interval{std::chrono::milliseconds{50}};
  // How long a send may wait for room when the device queue is full (ENOBUFS).
  std::chrono::nanoseconds send_max_wait{std::chrono::milliseconds{1}};
  // How often a lost interface is checked for and the socket reopened.
  std::chrono::nanoseconds reopen_interval{std::chrono::milliseconds{200}};
  // With a thermal acceleration other than 1: run the thermal network at real time while the
  // node's THERMAL_ESTIMATE says Calibrating, as pmsm-thermald runs its model
  // (controller.thermal.calibration_real_time) and as `pmsm-thermal simulate` runs both. The
  // frame must pass the bus's filters (main.cpp adds it).
  bool follow_calibration = false;
};

// The kernel filters pmsm-plant installs: its node's INVERTER_COMMAND and, when it follows the
// node's calibrations, its THERMAL_ESTIMATE.
[[nodiscard]] std::vector<hal::CanFilter> plant_receive_filters(const PlantNodeOptions& options);

// A consistent-enough copy of the counters (each field is read atomically; the set is not a
// single snapshot, which is fine for logs and summaries).
struct PlantNodeStats {
  std::uint64_t periods = 0;             // plant steps (simulated periods)
  double simulated_time_s = 0.0;
  std::uint64_t samples_sent = 0;        // SENSOR_SAMPLE frames sent, re-sends included
  std::uint64_t sample_resends = 0;      // lockstep: re-sends of an unanswered sample
  std::uint64_t bench_frames_sent = 0;   // TRUTH_THERMAL, TRUTH_ELECTRICAL, PLANT_STATUS
  std::uint64_t commands_applied = 0;    // commands used for the period they were meant for
  std::uint64_t stale_commands = 0;      // lockstep: an older sequence than awaited
  std::uint64_t duplicate_commands = 0;  // lockstep: the sequence just applied, again
  std::uint64_t future_commands = 0;     // a sequence the plant has not sent yet
  std::uint64_t late_commands = 0;       // real time: valid, but after their period
  std::uint64_t missing_commands = 0;    // real time: periods stepped without their command
  std::uint64_t command_timeouts = 0;    // real time: times the output was disabled
  bool command_timeout_tripped = false;  // real time: output disabled now
  bool output_enabled = false;           // the emulated gates switch in the current period
  bool waiting_for_controller = false;   // lockstep: the current sample had to be re-sent
  bool interface_down = false;           // the bus is gone; reopening
  bool calibration_real_time = false;    // following a calibration: thermal network at 1x now
  std::uint64_t calibrations_followed = 0;  // calibrations the thermal time followed
  // Frames the receiver rejected, by protocol::DecodeStatus (index kOk is unused).
  std::array<std::uint64_t, hal::protocol::kDecodeStatusCount> rejected{};
  std::uint64_t rx_errors = 0;           // failed reads
  std::uint64_t tx_dropped = 0;          // frames dropped: device queue full (ENOBUFS) after the wait
  std::uint64_t tx_failures = 0;         // other failed sends
  std::uint64_t interface_down_events = 0;
  std::uint64_t reopens = 0;             // successful reopen() calls after a loss
  std::uint64_t deadline_misses = 0;     // real time: wake-ups that found a deadline passed
  std::uint64_t missed_periods = 0;      // real time: deadlines skipped (simulated time fell behind)
  std::int64_t max_lateness_ns = 0;      // real time: worst wake-up latency

  [[nodiscard]] std::uint64_t rejected_total() const noexcept {
    std::uint64_t sum = 0;
    for (std::size_t i = 1; i < rejected.size(); ++i) {
      sum += rejected[i];
    }
    return sum;
  }
};

// kDiverged: the model's state stopped being a number (Plant::diverged), a machine its
// integration cannot follow; nothing it would send after that means anything.
enum class StopReason : std::uint8_t { kDuration, kStopRequested, kDiverged };

class PlantNode {
 public:
  // The bus must have CAN FD enabled (the fast frames are FD) and should carry the plant's
  // receive filters (main.cpp installs them); the node reads and writes it from run()'s
  // thread only. Throws ConfigError if an option is out of range.
  PlantNode(const PlantConfig& config, hal::CanBus& bus, const PlantNodeOptions& options);
  PlantNode(const PlantNode&) = delete;
  PlantNode& operator=(const PlantNode&) = delete;

  // Runs until the duration is reached or `stop` becomes true (checked at least every
  // resend interval in lockstep, every period in real time). Call once.
  StopReason run(const std::atomic<bool>& stop);

  // Any thread.
  [[nodiscard]] PlantNodeStats stats() const noexcept;

  [[nodiscard]] std::chrono::nanoseconds period() const noexcept { return period_; }
  [[nodiscard]] std::uint64_t truth_every_periods() const noexcept { return truth_every_; }
  // The plant itself, for tests after run() has returned (not while it runs).
  [[nodiscard]] const Plant& plant() const noexcept { return plant_; }

 private:
  // Written by the run() thread alone, read by anyone (hal/io counters.hpp).
  using Counter = hal::SingleWriterCounter;

  struct Counters {
    Counter periods, samples_sent, sample_resends, bench_frames_sent, commands_applied;
    Counter stale_commands, duplicate_commands, future_commands, late_commands;
    Counter missing_commands, command_timeouts;
    std::array<Counter, hal::protocol::kDecodeStatusCount> rejected;
    Counter rx_errors, tx_dropped, tx_failures, interface_down_events, reopens;
    Counter deadline_misses, missed_periods, max_lateness_ns;
    Counter calibrations_followed;
    std::atomic<bool> calibration_real_time{false};
    std::atomic<bool> command_timeout_tripped{false};
    std::atomic<bool> output_enabled{false};
    std::atomic<bool> waiting_for_controller{false};
    std::atomic<bool> interface_down{false};
  };

  // How a wait for a command ended.
  enum class Wake : std::uint8_t {
    kFrame,          // a valid INVERTER_COMMAND (any sequence)
    kNothing,        // time passed but nothing usable came (rejected frame, signal)
    kTimeout,        // the whole timeout passed (or, for a zero timeout, the queue is empty)
    kInterfaceDown,
    kError,
  };

  StopReason run_lockstep(const std::atomic<bool>& stop);
  StopReason run_realtime(const std::atomic<bool>& stop);

  // Waits up to `timeout` (0: only what is queued) for one frame; a valid INVERTER_COMMAND
  // comes back as kFrame, a rejected frame is counted and comes back as kNothing.
  Wake receive_command(std::chrono::nanoseconds timeout, hal::InverterCommand& out) noexcept;
  // Sends the current sample (and the bench frames when they are due); false if the
  // interface is gone.
  // A THERMAL_ESTIMATE of this node (options_.follow_calibration): the thermal time follows
  // its Calibrating bit; a frame that does not decode is counted as rejected.
  void follow_calibration(const hal::CanFrame& frame) noexcept;
  bool send_sample() noexcept;
  bool publish_bench_frames_if_due() noexcept;
  bool send(const hal::CanFrame& frame) noexcept;
  void step(const hal::InverterCommand& command) noexcept;
  // Blocks until the interface is back and the socket reopened, or stop is requested.
  bool recover_interface(const std::atomic<bool>& stop);
  [[nodiscard]] bool duration_reached() const noexcept;

  Plant plant_;
  hal::CanBus& bus_;
  PlantNodeOptions options_;
  hal::protocol::PlantReceiver receiver_;
  std::chrono::nanoseconds period_;
  std::uint64_t truth_every_ = 1;
  std::optional<std::uint64_t> stop_period_;
  hal::CanFrame frame_{};          // scratch, preallocated
  hal::ReceivedFrame received_{};  // scratch, preallocated
  // Lockstep: the last applied sequence, to tell duplicates from stale commands.
  std::optional<std::uint32_t> last_applied_sequence_;
  double thermal_acceleration_;    // the configuration's, restored after a calibration
  std::uint32_t thermal_estimate_id_;
  Counters counters_;
};

}  // namespace pmsm::plant
