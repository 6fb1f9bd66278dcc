#include "pmsm/core/supervisor.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace pmsm::core {

const char* to_string(DriveState state) noexcept {
  switch (state) {
    case DriveState::kInit: return "init";
    case DriveState::kStandby: return "standby";
    case DriveState::kRunning: return "running";
    case DriveState::kCalibrating: return "calibrating";
    case DriveState::kFault: return "fault";
  }
  return "?";
}

const char* to_string(FaultCode code) noexcept {
  switch (code) {
    case FaultCode::kNone: return "none";
    case FaultCode::kSensorTimeout: return "sensor-timeout";
    case FaultCode::kOvercurrent: return "overcurrent";
    case FaultCode::kOvertemperature: return "overtemperature";
    case FaultCode::kBusOff: return "bus-off";
    case FaultCode::kInterfaceDown: return "interface-down";
    case FaultCode::kCommandTimeout: return "command-timeout";
    case FaultCode::kGpioFault: return "gpio-fault";
    case FaultCode::kConfig: return "config";
    case FaultCode::kHardwareOvercurrent: return "hardware-overcurrent";
    case FaultCode::kDeadlineOverrun: return "deadline-overrun";
    case FaultCode::kCalibrationFailed: return "calibration-failed";
    case FaultCode::kStorage: return "storage";
    case FaultCode::kInternal: return "internal";
    case FaultCode::kDcBusUndervoltage: return "dc-bus-undervoltage";
    case FaultCode::kDcBusOvervoltage: return "dc-bus-overvoltage";
    case FaultCode::kInputNotFinite: return "input-not-finite";
    case FaultCode::kEncoderJump: return "encoder-jump";
    case FaultCode::kCurrentSum: return "current-sum";
    case FaultCode::kAmbientImplausible: return "ambient-implausible";
    case FaultCode::kOverspeed: return "overspeed";
    case FaultCode::kPeriodMismatch: return "period-mismatch";
    case FaultCode::kCurrentOffset: return "current-offset";
    case FaultCode::kOutputFeedback: return "output-feedback";
    case FaultCode::kDuplicateNode: return "duplicate-node";
    case FaultCode::kCount: break;
  }
  return "?";
}

Supervisor::Supervisor(const SupervisorConfig& config, double period_s)
    : config_(config),
      period_s_(period_s),
      // The most the shaft can turn in one period at the speed limit, with margin for the
      // encoder's quantisation and the speed limit itself being approximate.
      max_step_counts_(1.5 * config.max_speed_rad_s * period_s / (2.0 * std::numbers::pi) * config.encoder_counts + 2.0),
      // About 1 ms: a count of a 14-bit encoder is then 0.38 rad/s, and a runaway is caught
      // within a few milliseconds of crossing the limit.
      overspeed_window_periods_(std::max(1, static_cast<int>(std::lround(1e-3 / period_s)))) {}

void Supervisor::latch(FaultCode code) noexcept {
  const std::uint32_t b = bit(code);
  if ((status_.latched_mask & b) == 0U) {
    status_.latched_mask |= b;
    ++counts_[static_cast<std::size_t>(code)];
    latched_value_[static_cast<std::size_t>(code)] = cause_value_[static_cast<std::size_t>(code)];
    if (status_.first_fault == FaultCode::kNone) {
      status_.first_fault = code;
    }
  }
}

void Supervisor::cause(FaultCode code, double value) noexcept {
  cause_mask_ |= bit(code);
  cause_value_[static_cast<std::size_t>(code)] = value;
}

void Supervisor::report(FaultCode code, bool present) noexcept {
  if (present) {
    external_mask_ |= bit(code);
  } else {
    external_mask_ &= ~bit(code);
  }
}

void Supervisor::set_reported_period(double period_s, double step_s) noexcept {
  if (!(std::isfinite(period_s) && period_s > 0.0)) {
    status_.reported_period_s = 0.0;
    report(FaultCode::kPeriodMismatch, false);
    return;
  }
  status_.reported_period_s = period_s;
  // Within one step either way: the margin of 1e-6 of it keeps the rounding of code x step
  // from accepting one side and refusing the other.
  const double tolerance_s = std::max(std::isfinite(step_s) ? step_s : 0.0, 1e-3 * period_s_) * (1.0 + 1e-6);
  report(FaultCode::kPeriodMismatch, !(std::fabs(period_s - period_s_) <= tolerance_s));
}

void Supervisor::trip(FaultCode code) noexcept {
  latch(code);
  status_.state = DriveState::kFault;
  status_.power_stage_enabled = false;
}

void Supervisor::check_sample(const SupervisedSample& s) noexcept {
  const Abc& i = s.i_A;
  if (!std::isfinite(i.a) || !std::isfinite(i.b) || !std::isfinite(i.c) || !std::isfinite(s.vdc_V)) {
    cause_mask_ |= bit(FaultCode::kInputNotFinite);
    have_encoder_ = false;  // the encoder is judged afresh from the next sample on
    return;  // nothing else can be judged from NaN
  }
  if (s.vdc_V < config_.dc_bus_min_V) {
    cause(FaultCode::kDcBusUndervoltage, s.vdc_V);
  }
  if (s.vdc_V > config_.dc_bus_max_V) {
    cause(FaultCode::kDcBusOvervoltage, s.vdc_V);
  }
  if (const double largest = std::max({std::fabs(i.a), std::fabs(i.b), std::fabs(i.c)}); largest > config_.overcurrent_A) {
    cause(FaultCode::kOvercurrent, largest);
  }
  if (const double sum = std::fabs(i.a + i.b + i.c); sum > config_.current_sum_max_A) {
    cause(FaultCode::kCurrentSum, sum);
  }
  if (s.hardware_overcurrent) {
    cause_mask_ |= bit(FaultCode::kHardwareOvercurrent);
  }
  // The gates this drive means to switch (it runs or calibrates; a period without a sample in
  // between switches them off for that period alone and does not restart the count) against
  // what the stage reports; the stage applies a command a period or two later, so only a run of
  // samples counts.
  const bool meant_on = status_.state == DriveState::kRunning || status_.state == DriveState::kCalibrating;
  if (meant_on && !s.output_enabled) {
    ++output_off_samples_;
    if (config_.output_feedback_periods > 0 &&
        output_off_samples_ >= static_cast<std::uint32_t>(config_.output_feedback_periods)) {
      cause(FaultCode::kOutputFeedback, static_cast<double>(output_off_samples_));
    }
  } else {
    output_off_samples_ = 0;
  }
  // And the other way round: a stage that reports its gates switching while the drive holds them
  // off (a stage that ignores the enable, a stuck OutputEnabled). The power-up's current offsets
  // are measured only on samples with the gates off, so such a stage held the drive in INIT
  // without a fault or a word, and after INIT it went unnoticed (found by a review, 2026-12-05).
  // The value is the count, negative for this direction (the log tells the two apart).
  if (!meant_on && s.output_enabled) {
    ++output_on_samples_;
    if (config_.output_feedback_periods > 0 &&
        output_on_samples_ >= static_cast<std::uint32_t>(config_.output_feedback_periods)) {
      cause(FaultCode::kOutputFeedback, -static_cast<double>(output_on_samples_));
    }
  } else {
    output_on_samples_ = 0;
  }
  if (s.ambient_C && !(*s.ambient_C >= config_.ambient_min_C && *s.ambient_C <= config_.ambient_max_C)) {
    cause(FaultCode::kAmbientImplausible, *s.ambient_C);
  }
  const auto counts = static_cast<std::uint32_t>(config_.encoder_counts);
  if (s.encoder_count >= counts) {
    cause(FaultCode::kEncoderJump, static_cast<double>(s.encoder_count));  // not an angle this encoder can report
    have_encoder_ = false;
    return;
  }
  if (have_encoder_) {
    // Shortest way round, in counts; periods without a sample allow proportionally more.
    auto delta = static_cast<std::int64_t>(s.encoder_count) - static_cast<std::int64_t>(last_encoder_);
    const auto half = static_cast<std::int64_t>(counts / 2U);
    if (delta > half) {
      delta -= counts;
    } else if (delta < -half) {
      delta += counts;
    }
    const std::uint32_t elapsed = periods_without_sample_ + 1U;  // the periods the step spans
    const double allowed = max_step_counts_ * static_cast<double>(elapsed);
    if (std::fabs(static_cast<double>(delta)) > allowed) {
      cause(FaultCode::kEncoderJump, std::fabs(static_cast<double>(delta)));
    } else if (config_.overspeed_rad_s > 0.0) {
      // The shaft's speed over the window, from the counts it moved: judged once per window,
      // the cause held until the next window's answer.
      window_counts_ += delta;
      window_periods_ += elapsed;
      if (window_periods_ >= static_cast<std::uint32_t>(overspeed_window_periods_)) {
        const double speed_rad_s = std::fabs(static_cast<double>(window_counts_)) * (2.0 * std::numbers::pi) /
                                   (static_cast<double>(counts) * static_cast<double>(window_periods_) * period_s_);
        overspeed_cause_ = speed_rad_s > config_.overspeed_rad_s;
        cause_value_[static_cast<std::size_t>(FaultCode::kOverspeed)] = speed_rad_s;
        window_counts_ = 0;
        window_periods_ = 0;
      }
    }
  } else {
    window_counts_ = 0;  // a new angle: the window starts again
    window_periods_ = 0;
  }
  have_encoder_ = true;
  last_encoder_ = s.encoder_count;
}

const SupervisorStatus& Supervisor::step(const SupervisorInput& in) noexcept {
  cause_mask_ = external_mask_;

  if (in.sample) {
    if (status_.missing_samples >= static_cast<std::uint32_t>(config_.sensor_timeout_periods)) {
      // After a sensor loss nobody knows how far the shaft turned (a missing period may be a
      // long wait): the angle is taken afresh, not judged against the one before the loss.
      have_encoder_ = false;
    }
    // A sample that follows samples lost on the bus (SupervisorInput::periods > 1) spans them.
    periods_without_sample_ += std::max<std::uint32_t>(in.periods, 1U) - 1U;
    const std::uint32_t before = cause_mask_;
    check_sample(*in.sample);
    constexpr std::uint32_t kImplausibleFrame = bit(FaultCode::kInputNotFinite) | bit(FaultCode::kEncoderJump) |
                                                bit(FaultCode::kCurrentSum) | bit(FaultCode::kAmbientImplausible);
    sample_plausible_ = (cause_mask_ & ~before & kImplausibleFrame) == 0U;
    periods_without_sample_ = 0;
    ++present_samples_;
    if (present_samples_ >= static_cast<std::uint32_t>(config_.sensor_recovery_periods)) {
      // Losing the power stage's samples clears itself once they are back: the sensor
      // timeout, and a lost interface the caller no longer reports.
      status_.latched_mask &= ~bit(FaultCode::kSensorTimeout);
      if ((external_mask_ & bit(FaultCode::kInterfaceDown)) == 0U) {
        status_.latched_mask &= ~bit(FaultCode::kInterfaceDown);
      }
    }
    status_.missing_samples = 0;
  } else {
    sample_plausible_ = false;
    present_samples_ = 0;
    ++status_.missing_samples;
    periods_without_sample_ += std::max<std::uint32_t>(in.periods, 1U);
    if (status_.missing_samples >= static_cast<std::uint32_t>(config_.sensor_timeout_periods)) {
      cause(FaultCode::kSensorTimeout, static_cast<double>(status_.missing_samples));
    }
  }
  if (in.frontend_ready) {
    // Judged every period, not once: the cause stays while the offsets do, so that clearing
    // the fault cannot enable the gates on readings the offsets have made plausible.
    const Abc& o = in.current_offsets_A;
    const double largest = std::max({std::fabs(o.a), std::fabs(o.b), std::fabs(o.c)});
    if (!(largest <= config_.current_offset_max_A)) {
      cause(FaultCode::kCurrentOffset, largest);
    }
  }
  if (in.enable_requested && config_.command_timeout_s > 0.0 && !(in.command_age_s <= config_.command_timeout_s)) {
    cause(FaultCode::kCommandTimeout, in.command_age_s);
  }
  if (in.winding_C) {
    if (*in.winding_C > config_.trip_temp_C) {
      overtemp_cause_ = true;
      cause_value_[static_cast<std::size_t>(FaultCode::kOvertemperature)] = *in.winding_C;
    } else if (*in.winding_C < config_.trip_temp_C - config_.trip_hysteresis_C) {
      overtemp_cause_ = false;
    }
  }
  if (overtemp_cause_) {
    cause_mask_ |= bit(FaultCode::kOvertemperature);
  }
  if (overspeed_cause_) {
    cause_mask_ |= bit(FaultCode::kOverspeed);
  }

  // Every cause present latches its fault (counted once per latching). The common period has
  // none: no scan of every code then.
  for (std::size_t k = 1; cause_mask_ != 0U && k < kFaultCodeCount; ++k) {
    const auto code = static_cast<FaultCode>(k);
    if ((cause_mask_ & bit(code)) != 0U) {
      latch(code);
    }
  }
  if (clear_requested_) {
    clear_requested_ = false;
    // A fault judged on a sample's readings clears only on a sample that shows its cause gone:
    // in a period without one nothing was judged, and a stop there cleared them all (a stage
    // that latched its own over-current and fell silent), to be latched and counted again on the
    // next sample (found by a review, 2026-12-05).
    constexpr std::uint32_t kJudgedOnSamples =
        bit(FaultCode::kInputNotFinite) | bit(FaultCode::kDcBusUndervoltage) | bit(FaultCode::kDcBusOvervoltage) |
        bit(FaultCode::kOvercurrent) | bit(FaultCode::kCurrentSum) | bit(FaultCode::kHardwareOvercurrent) |
        bit(FaultCode::kAmbientImplausible) | bit(FaultCode::kOutputFeedback);
    const std::uint32_t unjudged = in.sample ? 0U : kJudgedOnSamples;
    status_.latched_mask &= cause_mask_ | unjudged;
  }
  if (status_.latched_mask == 0U) {
    status_.first_fault = FaultCode::kNone;
  }

  status_.sample_usable = in.sample.has_value() && status_.latched_mask == 0U;
  if (status_.latched_mask != 0U) {
    status_.state = DriveState::kFault;
    status_.power_stage_enabled = false;
  } else if (!in.frontend_ready) {
    status_.state = DriveState::kInit;
    status_.power_stage_enabled = false;
  } else if (in.enable_requested) {
    status_.state = in.calibrating ? DriveState::kCalibrating : DriveState::kRunning;
    // A missing sample (shorter than the timeout) switches the gates off for that period.
    status_.power_stage_enabled = status_.sample_usable;
  } else {
    status_.state = DriveState::kStandby;
    status_.power_stage_enabled = false;
  }
  return status_;
}

}  // namespace pmsm::core
