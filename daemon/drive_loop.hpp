// pmsm-thermald's real-time loop: event-driven by the sensor frame.
//
//   receive -> decode (E2E-checked commands update the operator's inputs; a sample goes on)
//           -> DriveNode::step -> encode -> send INVERTER_COMMAND
//           -> the period's publications into the SPSC ring (a normal thread sends them)
//
// A missing sample is noticed by the wait's deadline (can.sample_timeout_ms after the last
// one): the node then steps without a sample, so the supervisor counts it and, after
// supervisor.sensor_timeout_periods, latches the sensor-timeout fault, even when the plant is
// silent. A re-sent sample (same sequence: the plant did not hear our command) is answered
// with the same command, not stepped twice.
//
// After start-up the loop allocates nothing, logs nothing, takes no lock and throws nothing;
// its counters are single-writer atomics that any thread may read.
#pragma once

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <limits>
#include <optional>

#include "daemon_config.hpp"
#include "drive_node.hpp"
#include "pmsm/core/inverter_sweep.hpp"
#include "pmsm/hal/can_bus.hpp"
#include "pmsm/hal/codec.hpp"
#include "pmsm/hal/counters.hpp"
#include "pmsm/hal/rt.hpp"
#include "pmsm/hal/spsc_ring.hpp"

namespace pmsm::daemon {

// What leaves the RT thread each period that has something to say.
struct PublicationRecord {
  app::NodePublications publications;
  std::optional<core::Calibration> calibration_to_store;
  // The calibration in use took its Ke0 from turning events (it ran at rest), for the log and the
  // calibration file: where the rotor was taken to be, its standard uncertainty, the events.
  std::optional<core::Calibration> magnet_reference_to_store;
  double magnet_reference_at_C = 0.0;
  double magnet_reference_std_C = 0.0;
  int magnet_reference_events = 0;
  // The calibration's bridge sweep, in the period it ended (whatever its outcome), for the log.
  std::optional<core::InverterSweepResult> inverter_sweep;
  bool inverter_sweep_pending = false;  // ... and the controller will start it again
  // The calibration's rotor-angle check, in the period it ended, and the correction in use then.
  std::optional<core::AngleCheckResult> angle_check;
  bool angle_check_pending = false;
  double angle_correction_rad = 0.0;
  // With each heartbeat: the loop's timing since the previous one (LOOP_TIMING).
  std::optional<hal::protocol::LoopTiming> timing;
  // Every kThermalStateEvery_s of drive time, once the filter has an output: its state, for
  // the thermal state file.
  std::optional<core::ThermalState> thermal_state;
  double ambient_C = 25.0;      // the ambient / coolant temperature in use (DriveNode::ambient_C)
  bool ambient_held = false;    // ... a sensor that stopped reporting, held (DriveNode::ambient_held)
  std::uint32_t ambient_dropouts = 0;  // DriveNode::ambient_dropouts: brief ones between two records too
  bool ambient_sensed = false;  // ... a sensor's reading, not the configured value (DriveNode::ambient_sensed)
  double restore_ambient_shift_C = 0.0;  // DriveNode::restore_ambient_shift_C
  bool calibration_failed = false;
  core::CalibrationFailure calibration_failure = core::CalibrationFailure::kNone;
  double calibration_rs0_ohm = 0.0;      // a refused calibration's Rs0 and its standard error
  double calibration_rs0_std_ohm = 0.0;
  double calibration_winding_rise_C = 0.0;  // kWindingWarm: the filter's winding above the ambient
  core::OutcomeCounts calibration_pairs{};   // the ended calibration's pairs, by outcome (a timeout's why)
  // With calibration_to_store or a refused measured Rs0: the events it averaged (fewer at its timeout).
  int calibration_events = 0;
  core::AbortCounts calibration_aborts{};    // its aborted pairs, by cause
  double uptime_s = 0.0;
  double current_noise_A = 0.0;  // the current sensors' noise the front end measured (or was given)
  double reported_period_s = 0.0;  // the power stage's sampling period, as it reports it (0: never)
  // With fault reports: what each fault's cause measured when it latched (Supervisor::latched_values).
  std::array<double, core::kFaultCodeCount> fault_values{};
  // The estimator's refusals so far (the publisher logs them when they grow): winding estimates
  // the thermal filter gated out, and EMF (magnet) readings refused, with the last one's reason.
  std::uint32_t estimates_gated = 0;
  std::uint32_t estimates_dropped_at_restart = 0;  // held field-weakening estimates a restart dropped
  std::uint32_t magnet_rejected = 0;
  core::MagnetRefusalReport magnet_refusal{};
};
using PublicationRing = hal::SpscRing<PublicationRecord, 512>;

// Sample receive -> command send, in log2 buckets of microseconds: bucket 0 is < 1 us,
// bucket k is [2^(k-1), 2^k) us, the last one everything above.
inline constexpr std::size_t kTimingBuckets = 16;

struct LoopStats {
  std::uint64_t periods = 0;             // node steps (with or without a sample)
  std::uint64_t samples = 0;             // SENSOR_SAMPLE frames stepped on
  std::uint64_t resent_samples = 0;      // the same sequence again: answered, not stepped
  std::uint64_t missing_samples = 0;     // deadlines without a sample
  std::uint64_t skipped_samples = 0;     // sequence numbers skipped (lost on the bus) within a sample timeout
  std::uint64_t stale_samples = 0;       // older than the last sample used (not a restarted count): dropped
  std::uint64_t commands_sent = 0;       // INVERTER_COMMAND frames
  std::array<std::uint64_t, 3> commands_accepted{};  // drive, injection, calibration
  std::array<std::uint64_t, hal::protocol::kDecodeStatusCount> rejected{};  // by DecodeStatus
  hal::protocol::DecodeStatus last_rejection = hal::protocol::DecodeStatus::kOk;  // kOk: none yet
  std::uint32_t last_rejected_id = 0;
  std::uint64_t tx_dropped = 0;
  std::uint64_t tx_failures = 0;
  std::uint64_t rx_errors = 0;
  // Frames the kernel dropped for the loop's socket, its receive buffer full (SO_RXQ_OVFL):
  // samples and commands that never reached the loop (the backend's count, kept over reopens).
  std::uint64_t rx_overflow = 0;
  std::uint64_t publications_dropped = 0;  // the ring was full: periodic values lost (later ones supersede them)
  // Records carrying an event (a fault latched or cleared, a calibration's edge, store or failure,
  // a sweep's or angle check's end: drive_loop.cpp) that found the ring full and waited in
  // the loop's backlog, and those lost because the backlog was full too.
  std::uint64_t events_held = 0;
  std::uint64_t events_lost = 0;
  std::uint64_t deadline_misses = 0;       // receive -> send longer than one control period
  // Frames dated by their receive timestamp alone, with no clock reading (the bus sent and waited
  // in one call: in_hand_ns()), and those of them a clock reading after their step found dated
  // late (the realtime offset had moved since it was read: read again, the reading taken).
  std::uint64_t stamp_dated_frames = 0;
  std::uint64_t stamp_dated_late = 0;
  std::uint64_t interface_losses = 0;
  std::uint64_t reopens = 0;
  bool interface_down = false;
  std::array<std::uint64_t, kTimingBuckets> timing_us{};
  std::uint64_t max_step_ns = 0;
};

inline constexpr double kThermalStateEvery_s = 10.0;

class DriveLoop {
 public:
  // `bus` carries the daemon's kernel filters (sensor samples and commands of this node)
  // and is used by the loop's thread only.
  DriveLoop(const DaemonConfig& config, hal::CanBus& bus, PublicationRing& ring);
  DriveLoop(const DriveLoop&) = delete;
  DriveLoop& operator=(const DriveLoop&) = delete;

  // How many records carrying an event wait when the ring is full (the drain thread stalled for
  // longer than the ring's 512 records last).
  static constexpr std::size_t kBacklogRecords = 64;

  // The error-frame classes the control socket should select (CanBus::set_error_mask): the
  // controller's bus-off and restart, and its state changes. A bus-off latches BUS_OFF.
  static constexpr std::uint32_t kErrorClasses =
      hal::kCanErrBusOff | hal::kCanErrRestarted | hal::kCanErrController;

  // Runs until `stop` becomes true (seen within one sample timeout), then tells the power stage
  // "off" (switch_off). Call once.
  void run(const std::atomic<bool>& stop);

  // Any thread.
  [[nodiscard]] LoopStats stats() const noexcept;
  // Advances while the loop runs: what the systemd watchdog is fed on.
  [[nodiscard]] std::uint64_t heartbeat() const noexcept { return counters_.periods.get(); }
  // A condition another thread watches (GPIO fault input): handed to the supervisor.
  // A report of "active" is kept until the control thread has stepped on it: a pulse the
  // watcher saw and then saw end before the next period must still trip the drive.
  void set_gpio_fault(bool active) noexcept {
    if (active) {
      gpio_fault_seen_.store(true, std::memory_order_relaxed);
    }
    gpio_fault_.store(active, std::memory_order_relaxed);
  }
  // Another sender of this node's frames (the publisher watches for them): handed to the
  // supervisor as DUPLICATE_NODE while `active`.
  void set_duplicate_node(bool active) noexcept { duplicate_node_.store(active, std::memory_order_relaxed); }
  // The power stage's gate enable as the loop last commanded it (for the GPIO output).
  [[nodiscard]] bool gates_enabled() const noexcept { return gates_enabled_.load(std::memory_order_relaxed); }

  // Before run(): where CLOCK_REALTIME - CLOCK_MONOTONIC is read from (hal::realtime_minus_
  // monotonic_ns unless changed). A seam for tests: the host's wall clock cannot be set by one,
  // but a source that moves stands for it (arrival_ns()).
  using RealtimeOffsetSource = std::int64_t (*)() noexcept;
  void use_realtime_offset_source(RealtimeOffsetSource source) noexcept { realtime_offset_source_ = source; }

  // The node, for tests after run() has returned.
  [[nodiscard]] const app::DriveNode& node() const noexcept { return node_; }
  // Before run(): the thermal state kept from before a restart, `downtime_s` old.
  void restore_thermal_state(const core::ThermalState& state, double downtime_s, double ambient_C) {
    node_.controller().restore_thermal_state(state, downtime_s, ambient_C);
  }

 private:
  void on_frame(const hal::CanFrame& frame, std::int64_t now_ns) noexcept;
  // The step stands for `periods` control periods: without a sample, a sample timeout's or an
  // outage slice's; with one, 1, or the periods since the last sample when the ones between
  // were lost on the bus (on_frame).
  void step(const hal::SensorSample* sample, std::int64_t received_ns, std::uint32_t periods) noexcept;
  // Sends the answer to a sample that arrived at `arrival_ns`: on a full transmit queue it waits
  // for room until that sample's period ends, not longer (a later command is stale, and the
  // wait would hold up the next sample); what cannot go is dropped and counted.
  // Where the bus sends and waits in one call (exchanges_in_one_call()), the answer is staged
  // instead, and run() sends it with its wait for the next frame; anything that would hold it
  // up (the once-a-second clock readings, a missing period, an interface recovery, the stop)
  // sends it first (flush_answer()). The step's latency then ends when the answer is staged,
  // before the call that sends it.
  void send_answer(const hal::CanFrame& frame, std::int64_t arrival_ns) noexcept;
  void flush_answer() noexcept;
  void count_send(hal::SendResult result) noexcept;
  [[nodiscard]] std::int64_t in_hand_ns(std::int64_t now, bool now_read, std::int64_t deadline) noexcept;
  void recover_interface(const std::atomic<bool>& stop) noexcept;
  void switch_off() noexcept;
  [[nodiscard]] std::int64_t sample_timeout_ns() const noexcept { return sample_timeout_ns_; }
  void record_timing(std::int64_t took_ns) noexcept;
  [[nodiscard]] hal::protocol::LoopTiming close_timing_window() noexcept;
  // Hands a record to the ring, after the backlog (order kept). A record that finds the ring
  // full is kept in the backlog if it carries an event (and counted as held), else dropped and
  // counted; an event that finds the backlog full too is lost and counted.
  void publish(const PublicationRecord& r) noexcept;
  // Moves what the backlog holds into the ring while it has room; whether the backlog is empty.
  bool flush_backlog() noexcept;

  // Events that found the ring full (kBacklogRecords): filled and emptied by this thread only.
  std::array<PublicationRecord, kBacklogRecords> backlog_{};
  std::size_t backlog_first_ = 0;
  std::size_t backlog_count_ = 0;

  app::DriveNode node_;
  hal::CanBus& bus_;
  PublicationRing& ring_;
  hal::protocol::NodeId node_id_;
  hal::protocol::DaemonReceiver receiver_;
  std::int64_t sample_timeout_ns_;
  std::int64_t reopen_interval_ns_;
  std::int64_t period_ns_;
  std::uint32_t offset_refresh_periods_;  // control periods in a second (realtime_offset_ns_)
  std::uint32_t missing_periods_;  // control periods in one sample timeout
  std::uint32_t outage_slice_periods_;  // in one slice of an interface outage (the shorter of the timeout and the reopen interval)
  double next_thermal_state_s_ = kThermalStateEvery_s;  // drive uptime of the next one
  bool exchange_;  // the bus sends and waits in one call: answers are staged (send_answer())
  bool calibrate_at_first_run_;
  app::NodeInputs inputs_{};
  std::optional<std::int64_t> last_drive_command_ns_;
  std::optional<std::uint32_t> last_sequence_;
  bool sample_missed_ = false;  // a step without a sample since the last sample (its time is counted)
  hal::InverterCommand last_command_{};
  std::int64_t after_ns_ = 0;  // the clock after the last command was sent (run() waits from it), else the frame's moment
  bool after_read_ = false;    // after_ns_ is a clock reading (a command was sent), not the frame's moment
  // CLOCK_REALTIME - CLOCK_MONOTONIC (hal::realtime_minus_monotonic_ns), read at the start, then
  // once a second of periods and when a frame's wait reads as a stall or a clock set
  // (arrival_ns()): how long a frame waited in the socket before the loop read it.
  static constexpr std::int64_t kNever = std::numeric_limits<std::int64_t>::min() / 2;
  RealtimeOffsetSource realtime_offset_source_ = hal::realtime_minus_monotonic_ns;
  std::int64_t realtime_offset_ns_ = 0;
  std::int64_t offset_read_ns_ = kNever;  // when it was last read (monotonic)
  // The receive timestamp (realtime) of the frame whose long wait a reading of the offset since
  // the last one found a real stall (kNoStall: none), and the realtime of that reading: the
  // frames stamped between the two are that stall's backlog.
  static constexpr std::int64_t kNoStall = std::numeric_limits<std::int64_t>::max();
  std::int64_t stall_stamp_ns_ = kNoStall;
  std::int64_t stall_read_realtime_ns_ = kNever;
  // The realtime (after the set) of the last reading that found the offset moved: a frame
  // stamped before it may be stamped on the clock before the set.
  std::int64_t moved_realtime_ns_ = kNever;
  std::uint32_t periods_since_offset_ = 0;
  // Reads the offset at `now_ns` (monotonic); whether it stood (moved by a millisecond at most).
  bool read_realtime_offset(std::int64_t now_ns) noexcept;
  [[nodiscard]] std::int64_t arrival_ns(std::int64_t read_ns) noexcept;
  hal::CanFrame frame_{};
  hal::CanFrame staged_frame_{};  // the answer run() sends next (answer_staged_)
  std::int64_t staged_deadline_ns_ = 0;  // its period's end: it may wait for room until then
  bool answer_staged_ = false;
  hal::ReceivedFrame received_{};
  // The timing window closed by each heartbeat (this thread only).
  std::array<std::uint32_t, kTimingBuckets> window_timing_{};
  std::uint64_t window_max_ns_ = 0;
  std::uint32_t window_misses_ = 0;
  std::atomic<bool> gpio_fault_{false};       // the line's level as last read
  std::atomic<bool> gpio_fault_seen_{false};  // active since the last step (sticky)
  std::atomic<bool> duplicate_node_{false};   // another sender of this node's frames, as last heard
  std::atomic<bool> gates_enabled_{false};

  struct Counters {
    hal::SingleWriterCounter periods, samples, resent_samples, missing_samples, skipped_samples, stale_samples, commands_sent;
    std::array<hal::SingleWriterCounter, 3> commands_accepted;
    std::array<hal::SingleWriterCounter, hal::protocol::kDecodeStatusCount> rejected;
    hal::SingleWriterCounter tx_dropped, tx_failures, rx_errors, publications_dropped, deadline_misses;
    hal::SingleWriterCounter stamp_dated_frames, stamp_dated_late;
    hal::SingleWriterCounter events_held, events_lost;
    hal::SingleWriterCounter interface_losses, reopens, max_step_ns;
    std::array<hal::SingleWriterCounter, kTimingBuckets> timing_us;
    std::atomic<bool> interface_down{false};
    std::atomic<std::uint32_t> last_rejection{0};  // DecodeStatus << 16 | CAN ID
  };
  Counters counters_;
};

}  // namespace pmsm::daemon
