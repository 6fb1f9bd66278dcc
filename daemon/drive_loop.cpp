#include "drive_loop.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdlib>
#include <thread>
#include <variant>

#include "pmsm/hal/rt.hpp"

namespace pmsm::daemon {
namespace {

namespace protocol = hal::protocol;
using std::chrono::nanoseconds;

core::DriveMode drive_mode(const protocol::DriveCommand& c) noexcept {
  if (!c.enable) {
    return core::DriveMode::kDisabled;
  }
  switch (c.mode) {
    case protocol::DriveMode::kTorque: return core::DriveMode::kTorque;
    case protocol::DriveMode::kSpeed: return core::DriveMode::kSpeed;
    case protocol::DriveMode::kDisabled: break;
  }
  return core::DriveMode::kDisabled;
}

std::size_t timing_bucket(std::int64_t ns) noexcept {
  const auto us = static_cast<std::uint64_t>(ns > 0 ? ns / 1000 : 0);
  const std::size_t width = std::bit_width(us);  // 0 for < 1 us
  return width < kTimingBuckets ? width : kTimingBuckets - 1;
}

// A record the publisher must not lose: a fault latched or cleared (not the repeats of latched
// ones), the THERMAL_ESTIMATE of a calibration's start or end (its Calibrating bit's edge, the
// only report of an operator's abort), a calibration to store or its failure, a bridge sweep's or
// an angle check's end. The rest of a record is a periodic value that the next one supersedes
// (THERMAL_ESTIMATE, DRIVE_STATUS, HEARTBEAT, LOOP_TIMING, the repeats of latched faults, the
// thermal state to keep, RESISTANCE_ESTIMATE with its EstimateCount) or a pair's report, several
// a second while injecting, whose loss its InjectionCount shows: those, held, would fill the
// backlog ahead of a calibration's end, and are taken out of a record that is held.
bool carries_event(const PublicationRecord& r) noexcept {
  return r.publications.fault_changed || r.publications.calibrating_changed || r.calibration_to_store.has_value() ||
         r.magnet_reference_to_store.has_value() || r.calibration_failed || r.inverter_sweep.has_value() || r.angle_check.has_value();
}

}  // namespace

DriveLoop::DriveLoop(const DaemonConfig& config, hal::CanBus& bus, PublicationRing& ring)
    : node_(config.controller, config.supervisor, config.publish),
      bus_(bus),
      ring_(ring),
      node_id_(static_cast<protocol::NodeId>(config.can.node)),
      receiver_(node_id_),
      sample_timeout_ns_(static_cast<std::int64_t>(config.can.sample_timeout_ms * 1e6)),
      reopen_interval_ns_(static_cast<std::int64_t>(config.can.reopen_interval_ms * 1e6)),
      period_ns_(static_cast<std::int64_t>(config.controller.drive.period_s * 1e9)),
      offset_refresh_periods_(static_cast<std::uint32_t>(std::max(1.0, std::round(1.0 / config.controller.drive.period_s)))),
      missing_periods_(static_cast<std::uint32_t>(std::max(1.0, std::round(config.can.sample_timeout_ms * 1e-3 / config.controller.drive.period_s)))),
      outage_slice_periods_(static_cast<std::uint32_t>(
          std::max(1.0, std::round(std::min(config.can.sample_timeout_ms, config.can.reopen_interval_ms) * 1e-3 /
                                   config.controller.drive.period_s)))),
      exchange_(bus.exchanges_in_one_call()),
      calibrate_at_first_run_(config.startup.calibrate_if_missing && !config.controller.calibration_file.empty() &&
                              !config.controller.drive.calibration.calibrated) {}

void DriveLoop::send_answer(const hal::CanFrame& frame, std::int64_t arrival_ns) noexcept {
  // It may wait for room until the sample's period ends, on the clock the backend reads only
  // when the queue is full: not from the loop's last reading, which is the moment the sample
  // was in hand at best (run(): under User-Mode Linux a clock reading is a system call), and
  // let an answer wait past its period by the step's time and whatever preempted the thread.
  flush_answer();  // one answer per sample: an earlier one goes first
  if (exchange_) {
    // run() sends it with its wait for the next frame, in one system call.
    staged_frame_ = frame;
    staged_deadline_ns_ = arrival_ns + period_ns_;
    answer_staged_ = true;
    return;
  }
  count_send(bus_.send_before(frame, arrival_ns + period_ns_));
}

void DriveLoop::flush_answer() noexcept {
  if (answer_staged_) {
    answer_staged_ = false;
    count_send(bus_.send_before(staged_frame_, staged_deadline_ns_));
  }
}

void DriveLoop::count_send(hal::SendResult result) noexcept {
  switch (result) {
    case hal::SendResult::kOk:
      return;
    case hal::SendResult::kNoBufferSpace:
    case hal::SendResult::kWouldBlock:
      counters_.tx_dropped.bump();
      return;
    case hal::SendResult::kInterfaceDown:
      counters_.interface_down.store(true, std::memory_order_relaxed);
      return;
    case hal::SendResult::kInvalidFrame:
    case hal::SendResult::kError:
      break;
  }
  counters_.tx_failures.bump();
}

void DriveLoop::step(const hal::SensorSample* sample, std::int64_t received_ns, std::uint32_t periods) noexcept {
  inputs_.command_age_s = last_drive_command_ns_ ? static_cast<double>(received_ns - *last_drive_command_ns_) * 1e-9
                                                 : std::numeric_limits<double>::infinity();
  inputs_.deadline_misses = static_cast<std::uint32_t>(counters_.deadline_misses.get());
  inputs_.periods = periods;
  const bool pulse = gpio_fault_seen_.exchange(false, std::memory_order_relaxed);
  node_.report(core::FaultCode::kGpioFault, pulse || gpio_fault_.load(std::memory_order_relaxed));
  node_.report(core::FaultCode::kInterfaceDown, counters_.interface_down.load(std::memory_order_relaxed));
  node_.report(core::FaultCode::kDuplicateNode, duplicate_node_.load(std::memory_order_relaxed));
  // The controller's state as its error frames left it (kErrorClasses), an atomic the backend
  // keeps: bus-off until it restarts, or until the socket is reopened (it starts error-active).
  node_.report(core::FaultCode::kBusOff, bus_.state() == hal::CanBusState::kBusOff);
  // (Not while the ambient sensor is held at an old reading: it would be refused; the first run
  // with the sensor reporting again calibrates.)
  if (calibrate_at_first_run_ && node_.supervisor().status().state == core::DriveState::kRunning &&
      !node_.ambient_held()) {
    inputs_.start_calibration = true;  // at the ambient sensor's temperature
    calibrate_at_first_run_ = false;
  }

  const app::NodeStep& out = node_.step(sample, inputs_);
  // One-shot requests act once.
  inputs_.request_injection = false;
  inputs_.start_calibration = false;
  inputs_.calibration_known_C.reset();
  inputs_.abort_calibration = false;
  inputs_.clear_faults = false;

  if (out.command) {
    last_command_ = *out.command;
    gates_enabled_.store(out.command->enable, std::memory_order_relaxed);
    (void)protocol::encode(*out.command, node_id_, frame_);
    send_answer(frame_, received_ns);
    counters_.commands_sent.bump();
    after_ns_ = hal::monotonic_ns();
    after_read_ = true;
    if (received_ns > after_ns_) {
      // Dated by its receive timestamp through an offset that moved since it was read
      // (in_hand_ns()): the sample was in hand before this reading. The offset is read again; the
      // latency and the answer's period count from the reading.
      counters_.stamp_dated_late.bump();
      (void)read_realtime_offset(after_ns_);
      received_ns = after_ns_;
      staged_deadline_ns_ = std::min(staged_deadline_ns_, after_ns_ + period_ns_);
      after_ns_ = hal::monotonic_ns();  // after the offset's readings (system calls)
    }
    record_timing(after_ns_ - received_ns);
  } else {
    // No sample to answer: the drive's last answer no longer holds (a repeat of that sample
    // gets "off", on_frame()).
    last_command_.enable = false;
    gates_enabled_.store(false, std::memory_order_relaxed);
  }
  counters_.periods.bump();
  if (++periods_since_offset_ >= offset_refresh_periods_) {
    // Once a second of control periods (the wall clock may have been set or slewed).
    periods_since_offset_ = 0;
    flush_answer();  // not held up by the readings
    read_realtime_offset(after_ns_);
    if (after_read_) {
      // Its readings take system calls (under User-Mode Linux a few hundred microseconds): the
      // next wait starts from the clock after them, or a sample that came meanwhile would be
      // dated before them (run()).
      after_ns_ = hal::monotonic_ns();
    }
  }

  const app::NodePublications& p = out.publications;
  // The thermal state goes every kThermalStateEvery_s whether or not anything else is published
  // (with every publish.* period at 0 it went only at a clean stop).
  const bool thermal_state_due =
      node_.uptime_s() >= next_thermal_state_s_ && node_.controller().telemetry().thermal_valid;
  if (p.thermal || p.resistance || p.injection || p.status || p.heartbeat || p.fault_count > 0 ||
      out.calibration_to_store || out.magnet_reference_to_store || out.calibration_failed ||
      node_.controller().inverter_sweep_completed() ||
      node_.controller().angle_check_completed() || thermal_state_due) {
    PublicationRecord r;
    r.publications = p;
    r.calibration_to_store = out.calibration_to_store;
    if (out.magnet_reference_to_store) {
      const core::DriveTelemetry& t = node_.controller().telemetry();
      r.magnet_reference_to_store = out.magnet_reference_to_store;
      r.magnet_reference_at_C = t.magnet_reference_at_C;
      r.magnet_reference_std_C = t.magnet_reference_std_C;
      r.magnet_reference_events = t.magnet_reference_events;
    }
    r.inverter_sweep = node_.controller().inverter_sweep_completed();
    r.inverter_sweep_pending = node_.controller().inverter_sweep_pending();
    r.angle_check = node_.controller().angle_check_completed();
    r.angle_check_pending = node_.controller().angle_check_pending();
    r.angle_correction_rad = node_.controller().angle_correction_rad();
    r.calibration_failed = out.calibration_failed;
    if (out.calibration_to_store || out.calibration_failed) {
      const core::DriveTelemetry& t = node_.controller().telemetry();
      r.calibration_pairs = t.calibration_outcomes;
      r.calibration_aborts = t.calibration_aborts;
      const bool measured = out.calibration_to_store || core::refused_measured_rs0(t.calibration_failure);
      r.calibration_events = measured ? t.calibration_events : 0;
      if (out.calibration_failed) {
        r.calibration_failure = t.calibration_failure;
        r.calibration_winding_rise_C = t.calibration_winding_rise_C;
        if (measured) {
          r.calibration_rs0_ohm = t.calibration_rs0_ohm;
          r.calibration_rs0_std_ohm = t.calibration_rs0_std_ohm;
        }
      }
    }
    r.uptime_s = node_.uptime_s();
    r.current_noise_A = node_.frontend().current_noise_A();
    r.reported_period_s = node_.supervisor().status().reported_period_s;
    if (p.fault_count > 0) {
      r.fault_values = node_.supervisor().latched_values();
    }
    {
      const core::DriveTelemetry& t = node_.controller().telemetry();
      r.estimates_gated = t.estimates_gated;
      r.estimates_dropped_at_restart = t.estimates_dropped_at_restart;
      r.magnet_rejected = t.magnet_rejected;
      r.magnet_refusal = t.magnet_last_refusal;
    }
    if (p.heartbeat) {
      r.timing = close_timing_window();
    }
    if (thermal_state_due) {
      next_thermal_state_s_ = r.uptime_s + kThermalStateEvery_s;
      r.thermal_state = node_.controller().thermal_state();
    }
    r.ambient_C = node_.ambient_C();
    r.ambient_held = node_.ambient_held();
    r.ambient_dropouts = node_.ambient_dropouts();
    r.ambient_sensed = node_.ambient_sensed();
    r.restore_ambient_shift_C = node_.restore_ambient_shift_C();
    publish(r);
  } else if (backlog_count_ > 0U) {
    (void)flush_backlog();
  }
}

bool DriveLoop::flush_backlog() noexcept {
  while (backlog_count_ > 0U) {
    if (!ring_.try_push(backlog_[backlog_first_])) {
      return false;
    }
    backlog_first_ = (backlog_first_ + 1U) % kBacklogRecords;
    --backlog_count_;
  }
  return true;
}

void DriveLoop::publish(const PublicationRecord& r) noexcept {
  if (flush_backlog() && ring_.try_push(r)) {
    return;
  }
  if (!carries_event(r)) {
    counters_.publications_dropped.bump();
    return;
  }
  if (backlog_count_ == kBacklogRecords) {
    counters_.events_lost.bump();
    return;
  }
  // Held, the record keeps its events only: its periodic values would go out late, in a burst,
  // after newer ones (an old thermal state would be stored as the present one).
  PublicationRecord& held = backlog_[(backlog_first_ + backlog_count_) % kBacklogRecords];
  held = r;
  app::NodePublications& p = held.publications;
  if (!p.calibrating_changed) {
    p.thermal.reset();
  }
  p.resistance.reset();
  p.injection.reset();
  p.status.reset();
  p.heartbeat.reset();
  if (!p.fault_changed) {
    p.fault_count = 0;
  }
  held.timing.reset();
  held.thermal_state.reset();
  ++backlog_count_;
  counters_.events_held.bump();
}

void DriveLoop::record_timing(std::int64_t took_ns) noexcept {
  const auto took = static_cast<std::uint64_t>(took_ns > 0 ? took_ns : 0);
  const std::size_t bucket = timing_bucket(took_ns);
  counters_.timing_us[bucket].bump();
  counters_.max_step_ns.raise_to(took);
  ++window_timing_[bucket];
  window_max_ns_ = std::max(window_max_ns_, took);
  if (took_ns > period_ns_) {
    counters_.deadline_misses.bump();
    ++window_misses_;
  }
}

protocol::LoopTiming DriveLoop::close_timing_window() noexcept {
  protocol::LoopTiming t;
  std::uint64_t total = 0;
  for (const std::uint32_t n : window_timing_) {
    total += n;
  }
  // The upper bound (us) of the bucket holding the q-quantile: bucket k holds [2^(k-1), 2^k).
  auto bound = [&](std::uint64_t rank) {
    std::uint64_t seen = 0;
    for (std::size_t k = 0; k < kTimingBuckets; ++k) {
      seen += window_timing_[k];
      if (seen >= rank) {
        return static_cast<double>(std::uint64_t{1} << k);
      }
    }
    return static_cast<double>(std::uint64_t{1} << (kTimingBuckets - 1));
  };
  if (total > 0U) {
    t.latency_p50_us = bound((total + 1) / 2);
    t.latency_p99_us = bound(total - total / 100);
  }
  t.latency_max_us = static_cast<double>(window_max_ns_) * 1e-3;
  t.periods = static_cast<std::uint32_t>(std::min<std::uint64_t>(total, UINT32_MAX));
  t.deadline_misses = window_misses_;
  window_timing_.fill(0);
  window_max_ns_ = 0;
  window_misses_ = 0;
  return t;
}

void DriveLoop::on_frame(const hal::CanFrame& frame, std::int64_t now_ns) noexcept {
  const protocol::DaemonInput input = receiver_.receive(frame, nanoseconds{now_ns});
  if (const auto* sample = std::get_if<hal::SensorSample>(&input)) {
    if (last_sequence_ && sample->sequence == *last_sequence_) {
      // The plant did not hear our answer and sent the sample again: the same answer. It is no
      // fresh sample: it neither steps the drive nor moves the sample deadline, so a power
      // stage that repeats one sample (a frozen counter, a replaying gateway) runs into the
      // sensor timeout like a silent one; and once a period went missing since, the answer
      // given then is stale and the repeat is answered "off" (step()).
      counters_.resent_samples.bump();
      (void)protocol::encode(last_command_, node_id_, frame_);
      send_answer(frame_, now_ns);
      return;
    }
    if (last_sequence_ && !sample_missed_ && sample->sequence >= missing_periods_ &&
        sample->sequence - *last_sequence_ >= 0x80000000U) {
      // Older than the last sample used (the difference wraps to the upper half of the count)
      // and not a count that restarted from zero: a second power stage on this node's
      // identifiers, a replaying gateway, a frame held up somewhere. Stepping it would move
      // the drive's clocks by a wrapped gap (before: an outage of a sample timeout per frame,
      // the speed read as 0 while the shaft turned) and answering it would command a period
      // that is gone: dropped, counted, logged once a second (Publisher::report).
      counters_.stale_samples.bump();
      return;
    }
    counters_.samples.bump();
    // Sequence numbers skipped since the last sample (lost on the bus, the power stage running on
    // at its own pace) while no sample timeout fired: this sample stands for the periods since
    // the last one, and the drive's clocks and angle tracker take them. A larger jump (a power
    // stage that restarted its count) is an outage of unknown length first: the rotor is then
    // located afresh. After a timeout its time is counted already: a sample as after any wait.
    const std::uint32_t gap = last_sequence_ ? sample->sequence - *last_sequence_ : 1U;
    last_sequence_ = sample->sequence;
    if (sample_missed_ || gap == 1U) {
      sample_missed_ = false;
      step(sample, now_ns, 1);
    } else if (gap <= missing_periods_) {
      counters_.skipped_samples.bump(gap - 1U);
      step(sample, now_ns, gap);
    } else {
      counters_.missing_samples.bump();
      step(nullptr, now_ns, missing_periods_);
      step(sample, now_ns, 1);
    }
  } else if (const auto* drive = std::get_if<protocol::DriveCommand>(&input)) {
    counters_.commands_accepted[0].bump();
    last_drive_command_ns_ = now_ns;
    inputs_.mode = drive_mode(*drive);
    inputs_.speed_ref_rad_s = drive->speed_setpoint_rad_s;
    inputs_.torque_ref_Nm = drive->torque_setpoint_Nm;
    // A command to stop clears the faults whose cause is gone (as moteus's stop does), unless it
    // came through a disturbed stream: acted on there because it can only stop (a garbage frame
    // may pass as one), it must not acknowledge the faults too.
    if ((!drive->enable || drive->mode == protocol::DriveMode::kDisabled) &&
        !receiver_.disturbed(protocol::CommandStream::kDrive, nanoseconds{now_ns})) {
      inputs_.clear_faults = true;
    }
  } else if (const auto* injection = std::get_if<protocol::InjectionCommand>(&input)) {
    counters_.commands_accepted[1].bump();
    const app::CoreInjectionMethod m = app::core_injection_method(injection->method);
    node_.configure_injection(m.method, m.separation, injection->amplitude_A, injection->interval_s);
    // A request is kept until the step takes it, whatever frame of the stream follows it.
    inputs_.request_injection = inputs_.request_injection || injection->request_now;
  } else if (const auto* calibration = std::get_if<protocol::CalibrationCommand>(&input)) {
    counters_.commands_accepted[2].bump();
    if (calibration->action == protocol::CalibrationAction::kStart) {
      inputs_.start_calibration = true;
      inputs_.calibration_known_C = calibration->known_temp_C;
    } else if (calibration->action == protocol::CalibrationAction::kAbort) {
      inputs_.abort_calibration = true;
    }
  } else if (const auto* rejected = std::get_if<protocol::Rejected>(&input)) {
    counters_.rejected[static_cast<std::size_t>(rejected->reason)].bump();
    counters_.last_rejection.store(static_cast<std::uint32_t>(rejected->reason) << 16U | (rejected->can_id & 0xFFFFU),
                                   std::memory_order_relaxed);
  }
}

void DriveLoop::recover_interface(const std::atomic<bool>& stop) noexcept {
  flush_answer();  // as if it had gone when the step made it: refused and counted
  counters_.interface_losses.bump();
  counters_.interface_down.store(true, std::memory_order_relaxed);
  // The drive keeps its own time meanwhile: every slice of the wait (a sample timeout, or the
  // reopen interval if shorter) is a step without a sample standing for that slice's periods
  // (the fault is latched and queued for publication once the bus is back).
  const bool back = hal::wait_and_reopen(bus_, nanoseconds{reopen_interval_ns_}, nanoseconds{sample_timeout_ns_}, stop, [this] {
    counters_.missing_samples.bump();
    sample_missed_ = true;
    step(nullptr, hal::monotonic_ns(), outage_slice_periods_);
  });
  if (back) {
    counters_.reopens.bump();
    counters_.interface_down.store(false, std::memory_order_relaxed);
    last_sequence_.reset();
  }
}

bool DriveLoop::read_realtime_offset(std::int64_t now_ns) noexcept {
  constexpr std::int64_t kStood_ns = 1'000'000;
  const std::int64_t before = realtime_offset_ns_;
  realtime_offset_ns_ = realtime_offset_source_();
  const bool stood = offset_read_ns_ == kNever || std::abs(realtime_offset_ns_ - before) <= kStood_ns;
  offset_read_ns_ = now_ns;
  if (!stood) {
    moved_realtime_ns_ = now_ns + realtime_offset_ns_;
  }
  stall_stamp_ns_ = kNoStall;
  return stood;
}

// A frame's arrival on the monotonic clock: the kernel's software receive timestamp where the
// backend gives one (beside a hardware one, which is on the controller's own clock), else the
// moment it was in hand (`read_ns`: run()'s clock reading, or its last one plus the wait the
// backend accounted). A loop that was late to read a sample (its thread preempted, a burst of
// frames before it) was late to answer it: the step's latency and the deadline count from the
// arrival, and its answer may wait for room only until that period ends.
//   A wait that reads as a sample timeout or longer is a stall that long or a wall clock set
// back since the offset was read; one that reads more than a millisecond negative, a wall clock
// set forward. Either reads the offset again. A long wait counts in full, as a real stall, when
// that reading found the offset standing (within a millisecond) and the frame was stamped after
// the last reading that found it moved (a frame stamped before a set is off by the set, in
// either direction: a clock set by hours must not enter the latency figures, nor date a command
// back into a command timeout); so do the later frames of that stall's backlog, stamped between
// its frame and that reading, without another reading. Any other wait is taken with the offset
// as it stands, between none and one sample timeout. A frame on time ends the backlog. Other
// than for a long wait outside a backlog (and stamped after the last move), the offset is read
// at most once a sample timeout, and for a wall clock set forward once a second (not for each
// frame of a backend whose timestamps run ahead). A wait a little negative (the offset's own
// error) counts as none.
std::int64_t DriveLoop::arrival_ns(std::int64_t read_ns) noexcept {
  const std::int64_t stamp = received_.software_timestamp_ns;
  if (stamp == 0) {
    return read_ns;
  }
  constexpr std::int64_t kForward_ns = -1'000'000;
  constexpr std::int64_t kSecond_ns = 1'000'000'000;
  std::int64_t waited = read_ns + realtime_offset_ns_ - stamp;
  const bool long_wait = waited >= sample_timeout_ns_;
  if (!long_wait) {
    stall_stamp_ns_ = kNoStall;
  }
  if (long_wait || waited < kForward_ns) {
    const bool in_backlog = stamp >= stall_stamp_ns_ && stamp <= stall_read_realtime_ns_;
    // A frame stamped before the last move of the offset cannot be judged by reading it again.
    const bool judge_now = long_wait && !in_backlog && stamp > moved_realtime_ns_;
    // A wall clock set forward is read at most once a second (a backend whose timestamps run
    // ahead would otherwise cost a reading every sample timeout).
    const std::int64_t reread_after_ns = long_wait ? sample_timeout_ns_ : std::max(sample_timeout_ns_, kSecond_ns);
    if (judge_now || read_ns - offset_read_ns_ >= reread_after_ns) {
      const bool stood = read_realtime_offset(read_ns);
      waited = read_ns + realtime_offset_ns_ - stamp;
      if (stood && waited >= sample_timeout_ns_ && stamp > moved_realtime_ns_) {
        stall_stamp_ns_ = stamp;
        stall_read_realtime_ns_ = read_ns + realtime_offset_ns_;
      }
    }
    if (waited >= sample_timeout_ns_ && stamp >= stall_stamp_ns_ && stamp <= stall_read_realtime_ns_) {
      return read_ns - waited;
    }
  }
  return read_ns - std::clamp<std::int64_t>(waited, 0, sample_timeout_ns_);
}

// When the frame run() just received was in hand: its last clock reading plus the wait as the
// backend accounted it; for a wait the backend did not account (io_uring: one call sent the answer
// and waited), the frame's receive timestamp on the monotonic clock where it falls inside that
// wait, from the reading to the deadline (the frame came during the wait: in a lockstep period the
// sample comes after the answer; the loop had it a wake-up later, which arrival_ns() counts as
// none, as it counts any wait under a sample timeout); else (a frame queued before the wait, a
// wall clock set since the offset was read, no timestamp) the clock.
//   The offset is read once a second: one that moved since (a wall clock slewed or set by less
// than the window) dates the frame off by as much, late or early. Early counts as a longer wait,
// as a reading would. Late is caught by the clock reading after the step (step(): the frame was in
// hand before it), and the reading is taken instead (stamp_dated_late).
std::int64_t DriveLoop::in_hand_ns(std::int64_t now, bool now_read, std::int64_t deadline) noexcept {
  if (now_read && received_.waited_ns >= 0) {
    return now + received_.waited_ns;
  }
  if (exchange_ && now_read && received_.software_timestamp_ns != 0) {
    const std::int64_t stamped = received_.software_timestamp_ns - realtime_offset_ns_;
    if (stamped >= now && stamped <= deadline) {
      counters_.stamp_dated_frames.bump();
      return stamped;
    }
  }
  return hal::monotonic_ns();
}

void DriveLoop::run(const std::atomic<bool>& stop) {
  read_realtime_offset(hal::monotonic_ns());
  // In the steady state the clock is read once a period: after the command is sent, or staged
  // where the bus sends it with the wait for the next frame in one call (the step's latency).
  // The wait for the next sample starts from that reading, and the moment the sample is in hand
  // is that reading plus the wait as the kernel accounted it (SocketCanBus: ppoll's time left),
  // where the backend tells it, or its receive timestamp where one call sent and waited
  // (in_hand_ns()); else, and after a frame that sent no command, the clock is read again. A
  // wake-up without a sample reads the clock too. (Under User-Mode Linux a clock reading is a
  // system call, as costly as a frame's; on a controller with a vDSO it is tens of nanoseconds,
  // and the kernel's account of the wait is as good as a reading.)
  std::int64_t now = hal::monotonic_ns();
  bool now_read = true;  // `now` was read from the clock, with no wait since
  std::int64_t deadline = now + sample_timeout_ns_;
  while (!stop.load(std::memory_order_relaxed)) {
    if (now >= deadline) {
      // No sample within the timeout: a missing period for the supervisor. (An answer staged by a
      // step that ran past the deadline goes first, as it would have without the staging.)
      flush_answer();
      counters_.missing_samples.bump();
      after_ns_ = now;
      after_read_ = false;
      sample_missed_ = true;
      step(nullptr, now, missing_periods_);
      deadline = now + sample_timeout_ns_;
      now = after_ns_;
      now_read = now_read || after_read_;
      continue;
    }
    // The answer to the last sample goes with the wait for the next (one system call where the
    // backend has io_uring; send_answer() staged it), else it went when the step made it.
    const hal::ExchangeResult exchanged = bus_.send_and_receive(answer_staged_ ? &staged_frame_ : nullptr,
                                                                staged_deadline_ns_, received_, now, deadline);
    if (answer_staged_) {
      answer_staged_ = false;
      count_send(exchanged.sent);
    }
    switch (exchanged.received) {
      case hal::ReceiveStatus::kFrame: {
        const std::int64_t at = in_hand_ns(now, now_read, deadline);
        now = at;
        now_read = false;
        if (received_.frame.error) {
          // The backend keeps the controller's state from these (kErrorClasses); the next
          // step reports it (no samples come during a bus-off: a missing period).
          break;
        }
        const std::uint64_t samples_before = counters_.samples.get();
        after_ns_ = at;
        after_read_ = false;
        on_frame(received_.frame, arrival_ns(at));
        now = after_ns_;
        now_read = after_read_;
        if (counters_.samples.get() != samples_before) {
          // (A frame dated late by its timestamp, step(): from the reading after its step.)
          deadline = std::min(at, now) + sample_timeout_ns_;
        }
        break;
      }
      case hal::ReceiveStatus::kTimeout:
        now = hal::monotonic_ns();
        now_read = true;
        break;
      case hal::ReceiveStatus::kInterfaceDown:
        recover_interface(stop);
        now = hal::monotonic_ns();
        now_read = true;
        deadline = now + sample_timeout_ns_;
        break;
      case hal::ReceiveStatus::kError:
        counters_.rx_errors.bump();
        now = hal::monotonic_ns();
        now_read = true;
        break;
    }
    if (counters_.interface_down.load(std::memory_order_relaxed) && !stop.load(std::memory_order_relaxed)) {
      // A send found the interface gone.
      recover_interface(stop);
      now = hal::monotonic_ns();
      now_read = true;
      deadline = now + sample_timeout_ns_;
    }
  }
  switch_off();
  // What waits in the backlog goes before the drain thread stops (main.cpp stops it after run()
  // returns), if the ring makes room within a second.
  for (int k = 0; k < 1000 && !flush_backlog(); ++k) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  counters_.events_lost.bump(backlog_count_);
}

void DriveLoop::switch_off() noexcept {
  // The drive's last word to the power stage is "off": the answer to the next sample if one
  // comes within a sample timeout (a power stage in lockstep waits for it), else the last
  // answer repeated with the gates off. Without it a stopped daemon left the stage with its last
  // command, gates on, until the stage's own timeout.
  flush_answer();  // the answer to the last sample, as if it had gone when the step made it
  gates_enabled_.store(false, std::memory_order_relaxed);
  last_command_.enable = false;
  const std::int64_t until = hal::monotonic_ns() + sample_timeout_ns_;
  for (std::int64_t now = hal::monotonic_ns(); now < until; now = hal::monotonic_ns()) {
    if (bus_.receive(received_, nanoseconds{until - now}) != hal::ReceiveStatus::kFrame) {
      break;
    }
    const protocol::DaemonInput input = receiver_.receive(received_.frame, nanoseconds{now});
    if (const auto* sample = std::get_if<hal::SensorSample>(&input)) {
      last_command_.sequence = sample->sequence;
      break;
    }
  }
  (void)protocol::encode(last_command_, node_id_, frame_);
  if (bus_.send(frame_, std::chrono::microseconds{200}) == hal::SendResult::kOk) {
    counters_.commands_sent.bump();
  } else {
    counters_.tx_failures.bump();
  }
}

LoopStats DriveLoop::stats() const noexcept {
  LoopStats s;
  const Counters& c = counters_;
  s.periods = c.periods.get();
  s.samples = c.samples.get();
  s.resent_samples = c.resent_samples.get();
  s.missing_samples = c.missing_samples.get();
  s.skipped_samples = c.skipped_samples.get();
  s.stale_samples = c.stale_samples.get();
  s.commands_sent = c.commands_sent.get();
  for (std::size_t k = 0; k < s.commands_accepted.size(); ++k) {
    s.commands_accepted[k] = c.commands_accepted[k].get();
  }
  for (std::size_t k = 0; k < s.rejected.size(); ++k) {
    s.rejected[k] = c.rejected[k].get();
  }
  s.stamp_dated_frames = c.stamp_dated_frames.get();
  s.stamp_dated_late = c.stamp_dated_late.get();
  s.tx_dropped = c.tx_dropped.get();
  s.tx_failures = c.tx_failures.get();
  s.rx_errors = c.rx_errors.get();
  s.rx_overflow = bus_.counters().rx_overflow;  // (counters() may be read from any thread)
  s.publications_dropped = c.publications_dropped.get();
  s.events_held = c.events_held.get();
  s.events_lost = c.events_lost.get();
  s.deadline_misses = c.deadline_misses.get();
  s.interface_losses = c.interface_losses.get();
  s.reopens = c.reopens.get();
  s.interface_down = c.interface_down.load(std::memory_order_relaxed);
  for (std::size_t k = 0; k < kTimingBuckets; ++k) {
    s.timing_us[k] = c.timing_us[k].get();
  }
  s.max_step_ns = c.max_step_ns.get();
  const std::uint32_t last = c.last_rejection.load(std::memory_order_relaxed);
  s.last_rejection = static_cast<protocol::DecodeStatus>(last >> 16U);
  s.last_rejected_id = last & 0xFFFFU;
  return s;
}

}  // namespace pmsm::daemon
