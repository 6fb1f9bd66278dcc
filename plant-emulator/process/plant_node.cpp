#include "plant_node.hpp"

#include <time.h>

#include <cerrno>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <variant>

#include "pmsm/hal/protocol_filters.hpp"
#include "pmsm/hal/rt.hpp"

namespace pmsm::plant {
namespace {

using std::chrono::nanoseconds;
namespace protocol = hal::protocol;

// Sequence numbers wrap at 2^32 (five days at 10 kHz): compare them modulo 2^32, and read
// a difference of 2^31 or more as "ahead", not "far behind".
constexpr std::uint32_t kAheadThreshold = 0x8000'0000U;

// Sleeps without reading the clock afterwards; used only off the per-period path.
void sleep_for(nanoseconds duration) noexcept {
  timespec ts{};
  ts.tv_sec = duration.count() / 1'000'000'000;
  ts.tv_nsec = duration.count() % 1'000'000'000;
  (void)::clock_nanosleep(CLOCK_MONOTONIC, 0, &ts, nullptr);
}

std::uint32_t saturate_u32(std::uint64_t value) noexcept {
  return static_cast<std::uint32_t>(std::min<std::uint64_t>(value, std::numeric_limits<std::uint32_t>::max()));
}

}  // namespace

const char* to_string(RunMode mode) noexcept {
  return mode == RunMode::kLockstep ? "lockstep" : "realtime";
}

std::vector<hal::CanFilter> plant_receive_filters(const PlantNodeOptions& options) {
  const protocol::FilterSet filters = protocol::receive_filters(protocol::Role::kPlant, options.node);
  std::vector<hal::CanFilter> out(filters.view().begin(), filters.view().end());
  if (options.follow_calibration && options.node <= protocol::kMaxNodeId) {
    out.push_back(hal::CanFilter::exact(protocol::can_id(protocol::MessageType::kThermalEstimate, options.node), false));
  }
  return out;
}

std::uint64_t truth_every_periods(std::chrono::nanoseconds truth_period, double period_s) {
  const double truth_periods = static_cast<double>(truth_period.count()) * 1e-9 / period_s;
  return static_cast<std::uint64_t>(std::max(1.0, std::round(truth_periods)));
}

PlantNode::PlantNode(const PlantConfig& config, hal::CanBus& bus, const PlantNodeOptions& options)
    : plant_(config),
      bus_(bus),
      options_(options),
      receiver_(options.node),
      period_(0),
      thermal_acceleration_(config.thermal.acceleration),
      thermal_estimate_id_(protocol::can_id(protocol::MessageType::kThermalEstimate, options.node)) {
  if (options.node > protocol::kMaxNodeId) {
    throw std::invalid_argument("node id must be 0.." + std::to_string(protocol::kMaxNodeId) + ", got " +
                                std::to_string(options.node));
  }
  if (options.truth_period.count() <= 0 || options.command_timeout.count() <= 0 ||
      options.resend_interval.count() <= 0 || options.reopen_interval.count() <= 0 ||
      options.send_max_wait.count() < 0) {
    throw std::invalid_argument("truth period, command timeout, resend and reopen intervals must be > 0");
  }
  const double period_s = plant_.period_s();
  period_ = nanoseconds{std::llround(period_s * 1e9)};
  truth_every_ = plant::truth_every_periods(options.truth_period, period_s);
  if (options.duration_s) {
    if (!std::isfinite(*options.duration_s) || *options.duration_s < 0.0) {
      throw std::invalid_argument("duration must be a finite number of seconds >= 0");
    }
    stop_period_ = static_cast<std::uint64_t>(std::llround(*options.duration_s / period_s));
  }
}

StopReason PlantNode::run(const std::atomic<bool>& stop) {
  return options_.mode == RunMode::kLockstep ? run_lockstep(stop) : run_realtime(stop);
}

bool PlantNode::duration_reached() const noexcept {
  return stop_period_ && plant_.period() >= *stop_period_;
}

bool PlantNode::send(const hal::CanFrame& frame) noexcept {
  switch (bus_.send(frame, options_.send_max_wait)) {
    case hal::SendResult::kOk:
      return true;
    case hal::SendResult::kNoBufferSpace:
    case hal::SendResult::kWouldBlock:
      // The queue stayed full for the whole wait: the frame is lost. Lockstep re-sends an
      // unanswered sample; a lost bench frame is replaced by the next one.
      counters_.tx_dropped.bump();
      return true;
    case hal::SendResult::kInterfaceDown:
      counters_.interface_down_events.bump();
      return false;
    case hal::SendResult::kInvalidFrame:
    case hal::SendResult::kError:
      break;
  }
  counters_.tx_failures.bump();
  return true;
}

bool PlantNode::send_sample() noexcept {
  // A sample always encodes (its fields use the signals' full raw ranges).
  (void)protocol::encode(plant_.sample(), options_.node, frame_);
  counters_.samples_sent.bump();
  return send(frame_);
}

bool PlantNode::publish_bench_frames_if_due() noexcept {
  if (plant_.period() % truth_every_ != 0) {
    return true;
  }
  const PlantState state = plant_.state();
  const hal::TruthSample truth = plant_.truth();

  protocol::PlantStatus status;
  status.mode = options_.mode == RunMode::kLockstep ? protocol::PlantMode::kLockstep : protocol::PlantMode::kRealtime;
  status.output_enabled = state.gates_enabled;
  status.command_timeout_tripped = counters_.command_timeout_tripped.load(std::memory_order_relaxed);
  // In lockstep a command "after its period" is one whose sample has already been answered.
  status.late_commands = saturate_u32(options_.mode == RunMode::kLockstep
                                          ? counters_.stale_commands.get() + counters_.duplicate_commands.get()
                                          : counters_.late_commands.get());
  status.missing_commands = saturate_u32(counters_.missing_commands.get());
  status.simulated_time_s = plant_.time_s();

  // Telemetry may saturate (e.g. a temperature beyond the signal range): the frame is still
  // valid and says the most it can.
  bool up = true;
  (void)protocol::encode(protocol::truth_thermal_from(truth, state.ambient_C), options_.node, frame_);
  up = send(frame_) && up;
  (void)protocol::encode(protocol::truth_electrical_from(truth), options_.node, frame_);
  up = send(frame_) && up;
  (void)protocol::encode(status, options_.node, frame_);
  up = send(frame_) && up;
  counters_.bench_frames_sent.bump(3);
  return up;
}

void PlantNode::step(const hal::InverterCommand& command) noexcept {
  const hal::SensorSample& sample = plant_.step(command);
  counters_.periods.bump();
  counters_.output_enabled.store((sample.flags & hal::kSensorOutputEnabled) != 0, std::memory_order_relaxed);
}

PlantNode::Wake PlantNode::receive_command(nanoseconds timeout, hal::InverterCommand& out) noexcept {
  // The lockstep wait for a command is a backstop (the re-send of an unanswered sample after
  // tens of milliseconds): one blocking read per period where the bus allows it (SocketCAN:
  // SO_RCVTIMEO), and no clock reading unless a wake-up brings nothing usable.
  const hal::ReceiveStatus status =
      timeout.count() > 0 ? bus_.receive_backstop(received_, timeout) : bus_.receive(received_, timeout);
  switch (status) {
    case hal::ReceiveStatus::kFrame:
      break;
    case hal::ReceiveStatus::kTimeout:
      return Wake::kTimeout;
    case hal::ReceiveStatus::kInterfaceDown:
      counters_.interface_down_events.bump();
      return Wake::kInterfaceDown;
    case hal::ReceiveStatus::kError:
      counters_.rx_errors.bump();
      return Wake::kError;
  }
  if (received_.frame.error) {
    return Wake::kNothing;  // no error classes are selected; ignore any that arrive anyway
  }
  if (options_.follow_calibration && received_.frame.id == thermal_estimate_id_ && !received_.frame.extended) {
    follow_calibration(received_.frame);
    return Wake::kNothing;
  }
  const protocol::PlantInput input = receiver_.receive(received_.frame);
  if (const auto* command = std::get_if<hal::InverterCommand>(&input)) {
    out = *command;
    return Wake::kFrame;
  }
  if (const auto* rejected = std::get_if<protocol::Rejected>(&input)) {
    counters_.rejected[static_cast<std::size_t>(rejected->reason)].bump();
  }
  return Wake::kNothing;
}

void PlantNode::follow_calibration(const hal::CanFrame& frame) noexcept {
  protocol::ThermalEstimate estimate{};
  const protocol::DecodeStatus status = protocol::decode(frame, options_.node, estimate);
  if (status != protocol::DecodeStatus::kOk) {
    counters_.rejected[static_cast<std::size_t>(status)].bump();
    return;
  }
  if (estimate.calibrating == counters_.calibration_real_time.load(std::memory_order_relaxed)) {
    return;
  }
  // The temperatures carry on; only the time scale of the network changes (no allocation).
  plant_.set_thermal_acceleration(estimate.calibrating ? 1.0 : thermal_acceleration_);
  counters_.calibration_real_time.store(estimate.calibrating, std::memory_order_relaxed);
  if (estimate.calibrating) {
    counters_.calibrations_followed.bump();
  }
}

bool PlantNode::recover_interface(const std::atomic<bool>& stop) {
  counters_.interface_down.store(true, std::memory_order_relaxed);
  if (!hal::wait_and_reopen(bus_, options_.reopen_interval, std::chrono::milliseconds{50}, stop, [] {})) {
    return false;
  }
  counters_.reopens.bump();
  counters_.interface_down.store(false, std::memory_order_relaxed);
  return true;
}

StopReason PlantNode::run_lockstep(const std::atomic<bool>& stop) {
  const nanoseconds resend = options_.resend_interval;
  bool up = send_sample();
  up = publish_bench_frames_if_due() && up;
  // The wait for the command of the current sample. After every (re)send it is the whole
  // resend interval, without reading the clock; the clock is read only when a wake-up
  // brings nothing usable, and the first such wake-up fixes the deadline (so the re-send of
  // an unanswered sample comes at most two intervals late, whatever else arrives).
  nanoseconds wait = resend;
  bool deadline_set = false;
  std::int64_t deadline_ns = 0;
  const auto sent = [&] {
    wait = resend;
    deadline_set = false;
  };

  for (;;) {
    if (stop.load(std::memory_order_relaxed)) {
      return StopReason::kStopRequested;
    }
    if (duration_reached()) {
      return StopReason::kDuration;
    }
    if (plant_.diverged()) {
      return StopReason::kDiverged;
    }
    if (!up) {
      if (!recover_interface(stop)) {
        return StopReason::kStopRequested;
      }
      up = send_sample();
      sent();
      continue;
    }
    if (wait.count() <= 0) {
      // Nobody answered in time (no controller yet, or a frame was lost): send the same
      // sample again. Simulated time does not move.
      counters_.sample_resends.bump();
      counters_.waiting_for_controller.store(true, std::memory_order_relaxed);
      up = send_sample();
      sent();
      continue;
    }

    hal::InverterCommand command;
    const Wake wake = receive_command(wait, command);
    if (wake == Wake::kTimeout) {
      wait = nanoseconds{0};
      continue;
    }
    if (wake == Wake::kInterfaceDown) {
      up = false;
      continue;
    }
    if (wake == Wake::kError) {
      // Counted; a read error that repeats at once must not turn into a busy loop.
      sleep_for(std::chrono::milliseconds{1});
    }
    if (wake == Wake::kFrame) {
      const std::uint32_t k = plant_.period();
      const std::uint32_t behind = k - command.sequence;
      if (behind == 0) {
        step(command);
        last_applied_sequence_ = command.sequence;
        counters_.commands_applied.bump();
        counters_.waiting_for_controller.store(false, std::memory_order_relaxed);
        up = send_sample();
        up = publish_bench_frames_if_due() && up;
        sent();
        continue;
      }
      if (last_applied_sequence_ && command.sequence == *last_applied_sequence_) {
        counters_.duplicate_commands.bump();  // e.g. the answer to a re-sent sample
      } else if (behind < kAheadThreshold) {
        counters_.stale_commands.bump();
      } else {
        counters_.future_commands.bump();
      }
    }
    // Nothing usable: keep waiting until the deadline.
    const std::int64_t now_ns = hal::monotonic_ns();
    if (!deadline_set) {
      deadline_ns = now_ns + resend.count();
      deadline_set = true;
    }
    wait = nanoseconds{deadline_ns - now_ns};
  }
}

StopReason PlantNode::run_realtime(const std::atomic<bool>& stop) {
  const std::int64_t timeout_ns = options_.command_timeout.count();
  // A command computed from a sample older than the command timeout is not fresh: it proves
  // nothing about the controller being alive now.
  const auto fresh_window_periods =
      static_cast<std::uint32_t>(std::max<std::int64_t>(1, timeout_ns / std::max<std::int64_t>(1, period_.count())));

  hal::PeriodicTimer timer(period_);
  bool up = send_sample();
  up = publish_bench_frames_if_due() && up;
  timer.start();
  std::int64_t last_fresh_ns = hal::monotonic_ns();
  hal::InverterCommand held{};  // gates off until a command arrives
  bool tripped = false;

  for (;;) {
    if (stop.load(std::memory_order_relaxed)) {
      return StopReason::kStopRequested;
    }
    if (duration_reached()) {
      return StopReason::kDuration;
    }
    if (plant_.diverged()) {
      return StopReason::kDiverged;
    }
    if (!up) {
      if (!recover_interface(stop)) {
        return StopReason::kStopRequested;
      }
      up = send_sample();
      timer.start();  // no burst of "missed" periods for the outage
      continue;
    }

    const hal::PeriodicTimer::Tick tick = timer.wait_next();
    if (tick.missed_periods > 0) {
      // Simulated time falls behind the wall clock by the skipped periods (the plant steps
      // once per wake-up); counted as overruns.
      counters_.deadline_misses.bump();
      counters_.missed_periods.bump(tick.missed_periods);
    }
    if (static_cast<std::uint64_t>(tick.lateness_ns) > counters_.max_lateness_ns.get()) {
      counters_.max_lateness_ns.set(static_cast<std::uint64_t>(tick.lateness_ns));
    }
    const std::int64_t now_ns = tick.deadline_ns + tick.lateness_ns;
    const std::uint32_t k = plant_.period();

    // Everything that arrived during the period just ended.
    std::optional<hal::InverterCommand> on_time;
    std::optional<hal::InverterCommand> newest_late;
    for (;;) {
      hal::InverterCommand command;
      const Wake wake = receive_command(nanoseconds{0}, command);
      if (wake == Wake::kInterfaceDown) {
        up = false;
        break;
      }
      if (wake == Wake::kNothing) {
        continue;  // a rejected frame (counted); more may be queued
      }
      if (wake != Wake::kFrame) {
        break;
      }
      const std::uint32_t behind = k - command.sequence;
      if (behind == 0) {
        on_time = command;
        last_fresh_ns = now_ns;
      } else if (behind >= kAheadThreshold) {
        counters_.future_commands.bump();
      } else if (behind <= fresh_window_periods) {
        // Valid and recent, but after its period: a real power stage's registers would hold
        // these duties now, so they become the held command.
        counters_.late_commands.bump();
        if (!newest_late || k - newest_late->sequence > behind) {
          newest_late = command;
        }
        last_fresh_ns = now_ns;
      } else {
        counters_.stale_commands.bump();
      }
    }
    if (!up) {
      continue;
    }

    if (on_time) {
      held = *on_time;
      counters_.commands_applied.bump();
    } else {
      counters_.missing_commands.bump();
      if (newest_late) {
        held = *newest_late;
      }
    }
    const bool expired = now_ns - last_fresh_ns > timeout_ns;
    if (expired && !tripped) {
      counters_.command_timeouts.bump();
    }
    tripped = expired;
    counters_.command_timeout_tripped.store(tripped, std::memory_order_relaxed);

    // Safe torque off while the commands are missing: the gates open, the motor coasts.
    hal::InverterCommand applied = tripped ? hal::InverterCommand{} : held;
    applied.sequence = k;  // what the plant applies for period k + 1, whatever its origin
    step(applied);
    up = send_sample();
    up = publish_bench_frames_if_due() && up;
  }
}

PlantNodeStats PlantNode::stats() const noexcept {
  const Counters& c = counters_;
  PlantNodeStats s;
  s.periods = c.periods.get();
  s.simulated_time_s = static_cast<double>(s.periods) * static_cast<double>(period_.count()) * 1e-9;
  s.samples_sent = c.samples_sent.get();
  s.sample_resends = c.sample_resends.get();
  s.bench_frames_sent = c.bench_frames_sent.get();
  s.commands_applied = c.commands_applied.get();
  s.stale_commands = c.stale_commands.get();
  s.duplicate_commands = c.duplicate_commands.get();
  s.future_commands = c.future_commands.get();
  s.late_commands = c.late_commands.get();
  s.missing_commands = c.missing_commands.get();
  s.command_timeouts = c.command_timeouts.get();
  s.command_timeout_tripped = c.command_timeout_tripped.load(std::memory_order_relaxed);
  s.output_enabled = c.output_enabled.load(std::memory_order_relaxed);
  s.waiting_for_controller = c.waiting_for_controller.load(std::memory_order_relaxed);
  s.interface_down = c.interface_down.load(std::memory_order_relaxed);
  s.calibration_real_time = c.calibration_real_time.load(std::memory_order_relaxed);
  s.calibrations_followed = c.calibrations_followed.get();
  for (std::size_t i = 0; i < s.rejected.size(); ++i) {
    s.rejected[i] = c.rejected[i].get();
  }
  s.rx_errors = c.rx_errors.get();
  s.tx_dropped = c.tx_dropped.get();
  s.tx_failures = c.tx_failures.get();
  s.interface_down_events = c.interface_down_events.get();
  s.reopens = c.reopens.get();
  s.deadline_misses = c.deadline_misses.get();
  s.missed_periods = c.missed_periods.get();
  s.max_lateness_ns = static_cast<std::int64_t>(c.max_lateness_ns.get());
  return s;
}

}  // namespace pmsm::plant
