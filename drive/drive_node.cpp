#include "drive_node.hpp"

#include <algorithm>
#include <cmath>

namespace pmsm::app {
namespace {

namespace protocol = hal::protocol;

protocol::DriveState to_protocol(core::DriveState s) noexcept {
  return static_cast<protocol::DriveState>(static_cast<std::uint8_t>(s));
}

protocol::CalibrationResult to_protocol(core::CalibrationOutcome o) noexcept {
  switch (o) {
    case core::CalibrationOutcome::kNone: return protocol::CalibrationResult::kNone;
    case core::CalibrationOutcome::kDone: return protocol::CalibrationResult::kDone;
    case core::CalibrationOutcome::kAborted: return protocol::CalibrationResult::kAborted;
    case core::CalibrationOutcome::kTimedOut: return protocol::CalibrationResult::kTimedOut;
    case core::CalibrationOutcome::kRefused: return protocol::CalibrationResult::kRefused;
  }
  return protocol::CalibrationResult::kNone;
}

}  // namespace

core::SupervisorConfig default_supervisor_config(const ControllerConfig& config) {
  const core::DriveConfig& d = config.drive;
  core::SupervisorConfig s;
  // A bus 40 % low cannot drive the motor at its rated point; 25 % high is beyond what the
  // DC link of a drive built for this bus is rated for. Never above the ADC's full scale.
  s.dc_bus_min_V = 0.6 * config.nominal_dc_bus_V;
  s.dc_bus_max_V = std::min(1.25 * config.nominal_dc_bus_V, 0.98 * config.sensors.dc_bus_full_scale_V);
  // 90 % of the current ADC's range: a saturated reading is never a valid current.
  s.overcurrent_A = 0.9 * config.sensors.current_range_A;
  // Three healthy sensors sum to noise and gain error; 10 % of full scale is a broken one.
  s.current_sum_max_A = 0.1 * config.sensors.current_range_A;
  // A Hall or shunt amplifier's offset is a few tenths of a per cent of its range; 5 % is a
  // broken or stuck sensor (a frozen ADC reading 117 A with the gates off was taken as its
  // offset, and the drive enabled on it).
  s.current_offset_max_A = 0.05 * config.sensors.current_range_A;
  s.max_speed_rad_s = 3.0 * d.motor.rated_speed_rad_s;
  // Field weakening takes a drive above its rated speed; half as much again is a runaway.
  s.overspeed_rad_s = 1.5 * d.motor.rated_speed_rad_s;
  s.encoder_counts = 1 << d.angle.encoder_bits;
  s.trip_temp_C = d.derating.limit_C + 25.0;
  return s;
}

protocol::InjectionMethod protocol_method(core::InjectionMethod method, core::Separation separation) noexcept {
  const bool bipolar = separation == core::Separation::kBipolar;
  switch (method) {
    case core::InjectionMethod::kFixedMagnitude:
      return bipolar ? protocol::InjectionMethod::kFixedMagnitudeBipolar : protocol::InjectionMethod::kFixedMagnitudeUnipolar;
    case core::InjectionMethod::kFixedAngle:
      return bipolar ? protocol::InjectionMethod::kFixedAngleBipolar : protocol::InjectionMethod::kFixedAngleUnipolar;
    case core::InjectionMethod::kDc:
      return protocol::InjectionMethod::kDc;
    case core::InjectionMethod::kNone:
      break;
  }
  return protocol::InjectionMethod::kOff;
}

CoreInjectionMethod core_injection_method(protocol::InjectionMethod method) noexcept {
  switch (method) {
    case protocol::InjectionMethod::kFixedMagnitudeBipolar: return {core::InjectionMethod::kFixedMagnitude, core::Separation::kBipolar};
    case protocol::InjectionMethod::kFixedMagnitudeUnipolar:
      return {core::InjectionMethod::kFixedMagnitude, core::Separation::kUnipolar};
    case protocol::InjectionMethod::kFixedAngleBipolar: return {core::InjectionMethod::kFixedAngle, core::Separation::kBipolar};
    case protocol::InjectionMethod::kFixedAngleUnipolar: return {core::InjectionMethod::kFixedAngle, core::Separation::kUnipolar};
    case protocol::InjectionMethod::kDc: return {core::InjectionMethod::kDc, core::Separation::kBipolar};
    case protocol::InjectionMethod::kOff: break;
  }
  return {};
}

DriveNode::DriveNode(const ControllerConfig& config, const core::SupervisorConfig& supervisor, const PublishRates& rates)
    : controller_(config.drive),
      supervisor_(supervisor, config.drive.period_s),
      frontend_(config.sensors, config.drive.period_s),
      period_s_(config.drive.period_s),
      rates_(rates),
      thermal_every_(every(rates.thermal_estimate_s)),
      resistance_every_(every(rates.resistance_estimate_s)),
      status_every_(every(rates.drive_status_s)),
      heartbeat_every_(every(rates.heartbeat_s)),
      fault_every_(every(rates.fault_repeat_s)),
      thermal_time_scale_(config.drive.thermal.time_scale),
      calibration_real_time_(config.calibration_real_time) {}

std::uint64_t DriveNode::every(double seconds) const noexcept {
  if (!(seconds > 0.0)) {
    return 0;
  }
  return std::max<std::uint64_t>(1, static_cast<std::uint64_t>(std::llround(seconds / period_s_)));
}

const NodeStep& DriveNode::step(const hal::SensorSample* sample, const NodeInputs& in) noexcept {
  out_.command.reset();
  out_.publications.clear();
  out_.calibration_to_store.reset();
  out_.magnet_reference_to_store.reset();
  out_.calibration_failed = false;
  advance_ = std::max<std::uint64_t>(1U, in.periods);

  // Front end first: codes to amperes and volts, with the power-up offset calibration.
  core::DriveInput drive_in;
  drive_in.valid = false;
  core::SupervisorInput si;
  if (sample != nullptr) {
    drive_in = frontend_.convert(*sample);
    si.sample = core::SupervisedSample{drive_in.i_A, drive_in.vdc_V, drive_in.encoder_count,
                                       (sample->flags & hal::kSensorHardwareOvercurrent) != 0U,
                                       (sample->flags & hal::kSensorOutputEnabled) != 0U, std::nullopt};
    if ((sample->flags & hal::kSensorAmbientValid) != 0U) {
      si.sample->ambient_C = 0.01 * static_cast<double>(sample->ambient_centi_C);
    }
    if (sample->pwm_period_code != reported_period_code_) {
      // Judged when it changes (a new power stage), not every period. A held ambient reading
      // was the old stage's sensor's: not carried over.
      reported_period_code_ = sample->pwm_period_code;
      sensed_ambient_C_.reset();
      ambient_held_ = false;
      supervisor_.set_reported_period(hal::kPwmPeriodStep_s * static_cast<double>(reported_period_code_),
                                      hal::kPwmPeriodStep_s);
    }
  }
  si.periods = static_cast<std::uint32_t>(std::min<std::uint64_t>(advance_, 1000000U));
  si.frontend_ready = frontend_.ready();
  const std::array<double, 3>& offsets = frontend_.offsets_A();
  si.current_offsets_A = {offsets[0], offsets[1], offsets[2]};
  if (si.frontend_ready && !noise_known_) {
    // Once, when the offsets (and with them the sensors' noise) are known.
    controller_.set_current_noise_A(frontend_.current_noise_A());
    noise_known_ = true;
  }
  si.enable_requested = in.mode != core::DriveMode::kDisabled;
  si.calibrating = controller_.telemetry().calibrating;
  si.command_age_s = in.command_age_s;
  const core::ThermalEstimate& thermal = controller_.telemetry().thermal;
  if (controller_.telemetry().thermal_valid && std::isfinite(thermal.winding_C)) {
    si.winding_C = thermal.winding_C;
  }
  if (in.clear_faults) {
    supervisor_.request_clear();
  }
  const core::SupervisorStatus& status = supervisor_.step(si);
  // The ambient / coolant sensor of the sample, when the frame is plausible (an ambient out of
  // range, but also a reading not a number, an encoder or currents a sample cannot have: its
  // other readings are then suspect too; a bus switched off is a condition, not a bad frame) and
  // it is this stage's own (no second source, no other PWM period); without a
  // sensor (a power stage without one) the caller's value. A sensor that reported and then stops
  // (its stage's own sensor check, a loose connector) is held at its last reading: the boundary
  // of the thermal model does not jump to the caller's 25 C. Read through a latched fault too:
  // the controller sees no sample then, but its thermal model runs on, and a latched
  // OVERTEMPERATURE clears only as the winding cools towards this boundary.
  const bool ambient_read = si.sample && supervisor_.sample_plausible() &&
                            !supervisor_.cause_present(core::FaultCode::kPeriodMismatch) &&
                            !supervisor_.cause_present(core::FaultCode::kDuplicateNode);
  if (ambient_read) {
    const bool held = !si.sample->ambient_C && sensed_ambient_C_.has_value();
    ambient_dropouts_ += held && !ambient_held_ ? 1U : 0U;
    ambient_held_ = held;
    if (si.sample->ambient_C) {
      sensed_ambient_C_ = si.sample->ambient_C;
    }
  }
  const double ambient_C = sensed_ambient_C_.value_or(in.ambient_C);
  ambient_used_C_ = ambient_C;
  if (ambient_read && si.sample->ambient_C && !restore_referred_) {
    // The sensor's first plausible reading after the start: the ambient of the restart, against
    // the one a restored thermal state was cooled towards (a restore comes before the first
    // sample). Only a reading: a sensor that reports a few samples late would otherwise refer the
    // state to the configured ambient. The filter's first update ends the chance (a stage without
    // the sensor keeps the restore as cooled towards the stored ambient).
    restore_referred_ = true;
    restore_ambient_shift_C_ = controller_.refer_restored_state_to_ambient(ambient_C);
  }

  // A fault suspends a calibration (no pair runs in the safe state); it resumes once the fault
  // is cleared, within its timeout: a passing sensor timeout must not cost the commissioning.
  if (in.abort_calibration) {
    controller_.abort_calibration();
  }
  if (in.start_calibration && supervisor_.latched(core::FaultCode::kOvertemperature)) {
    // Not with OVERTEMPERATURE latched: a calibration starts the thermal filter again from the
    // temperature it is given, and the trip clears on the estimate. A reviewer found that an
    // operator's 25 C sent after the trip reset the estimate, and the next stop cleared the trip
    // with the winding still hot (docs/daemon.md, CALIBRATION_COMMAND). Other faults do not
    // refuse it: a calibration asked for while, say, SENSOR_TIMEOUT holds (a daemon started before
    // its power stage) waits for the fault to clear, as a running one does.
    controller_.refuse_calibration_while_overtemperature();
  } else if (in.start_calibration) {
    // The drive's own knowledge of the winding's temperature: the operator's value, or the
    // ambient / coolant sensor of a motor at rest (soaked).
    controller_.start_calibration(in.calibration_known_C.value_or(ambient_C), !in.calibration_known_C.has_value(),
                                  ambient_held_);
    // In an accelerated test the calibration runs at real thermal time, as on a machine: at
    // 400x the winding's own time constant shrinks to tens of milliseconds and its temperature
    // swings within an event (docs/hil.md).
    if (calibration_real_time_ && thermal_time_scale_ != 1.0 && controller_.telemetry().calibrating) {
      controller_.set_thermal_time_scale(1.0);
      real_time_calibration_ = true;
    }
  }

  // The controller sees a sample only when the supervisor found it plausible, and runs the
  // current loop only when the supervisor lets the power stage switch.
  drive_in.valid = drive_in.valid && status.sample_usable;
  drive_in.periods = si.periods;  // a timeout, or a sample after lost ones, stands for that many periods
  // The sample follows the last one the controller used by the periods it stands for (the power
  // stage's sequence): the shaft turned by that many periods since, whatever the wall clock did.
  drive_in.continuous = sample != nullptr && last_used_sequence_ &&
                        sample->sequence == *last_used_sequence_ + si.periods;
  if (sample != nullptr && drive_in.valid) {
    last_used_sequence_ = sample->sequence;
  }
  core::DriveCommand cmd;
  cmd.mode = status.power_stage_enabled ? in.mode : core::DriveMode::kDisabled;
  cmd.speed_ref_rad_s = in.speed_ref_rad_s;
  cmd.torque_ref_Nm = in.torque_ref_Nm;
  cmd.ambient_C = ambient_C;
  cmd.request_injection = in.request_injection;
  const core::DriveOutput& out = controller_.step(drive_in, cmd);
  // A command, or a winding estimate the filter calls valid, that is not a finite number: the
  // drive cannot trust its own arithmetic (never seen; the last line of defence).
  const core::DriveTelemetry& telemetry = controller_.telemetry();
  if (out.fault || (telemetry.thermal_valid && !(std::isfinite(telemetry.thermal.winding_C) &&
                                                 std::isfinite(telemetry.thermal.winding_std_C)))) {
    supervisor_.trip(core::FaultCode::kInternal);
  }
  if (sample != nullptr) {
    core::DriveOutput gated = out;
    gated.enable = out.enable && supervisor_.status().power_stage_enabled;
    out_.command = SensorFrontend::command(gated, sample->sequence);
  }
  if (controller_.calibration_completed()) {
    out_.calibration_to_store = *controller_.calibration_completed();
  }
  if (controller_.magnet_reference_completed()) {
    out_.magnet_reference_to_store = *controller_.magnet_reference_completed();
  }
  out_.calibration_failed = controller_.calibration_just_failed();
  if (real_time_calibration_ && !controller_.telemetry().calibrating) {
    // Done, failed or aborted: the test's thermal time again.
    controller_.set_thermal_time_scale(thermal_time_scale_);
    real_time_calibration_ = false;
  }

  if (controller_.motion_known()) {
    motion_known_until_ = period_ + advance_;
    if (status_every_ != 0U) {
      // DRIVE_STATUS's torque is the interval's mean (one sample's current noise and the pulses'
      // reluctance torque made it jump by several N m at no load).
      const core::Dq& i = controller_.telemetry().i_A;
      torque_iq_sum_A_ += i.q;
      torque_idiq_sum_A2_ += i.d * i.q;
      ++torque_samples_;
    }
  }
  publish(in);
  period_ += advance_;
  return out_;
}

void DriveNode::publish(const NodeInputs& in) noexcept {
  NodePublications& p = out_.publications;
  const core::DriveTelemetry& tel = controller_.telemetry();
  const core::SupervisorStatus& st = supervisor_.status();
  const double now_s = uptime_s();

  if (controller_.last_pair()) {
    const core::PairResult& r = *controller_.last_pair();
    protocol::InjectionReport rep;
    rep.injection_count = injection_count_++;
    rep.method = protocol_method(r.method, r.separation);  // the pair's own: a calibration's are its procedure's
    rep.result = static_cast<protocol::InjectionResult>(static_cast<std::uint8_t>(r.outcome));
    rep.amplitude_A = r.f_A;
    // A pair whose Rs rests on the configured guess of the bridge's voltage (a calibration's
    // first event, before its levels learned Vx) measured no Rs of its own: 0.17 and 0.24 ohm
    // were published as accepted measurements of a 0.133 ohm winding.
    rep.rs_valid = r.outcome == core::PairOutcome::kAccepted && std::isfinite(r.rs_ohm) && !r.rs_rests_on_vx_guess;
    rep.measured_rs_ohm = rep.rs_valid ? r.rs_ohm : 0.0;
    // Electrical to mechanical.
    // Both recordings' means exist only when the second matched samples of the first: an aborted
    // or skipped pair has none (its 0 is no measured "no change"), and a second recording that
    // matched nothing would read the whole speed as the change.
    rep.speed_change_valid = r.samples > 0U;
    rep.speed_change_rad_s = rep.speed_change_valid ? r.delta_omega_e_rad_s / controller_.config().motor.pole_pairs : 0.0;
    p.injection = rep;
  }
  // Only an estimate the thermal filter took: one its gate refused (an innovation beyond 6 sigma)
  // is a measurement the drive judged implausible, counted (estimates_gated) and not published
  // as the winding's resistance, at once or in the repeats after it.
  const bool new_estimate = controller_.last_estimate().has_value() && controller_.last_estimate()->fused;
  if (new_estimate) {
    last_estimate_ = *controller_.last_estimate();
    last_estimate_s_ = now_s;
    ++estimate_count_;
  }
  if ((new_estimate || due(resistance_every_)) && last_estimate_) {
    protocol::ResistanceEstimate r;
    r.valid = std::isfinite(last_estimate_->rs_ohm) && std::isfinite(last_estimate_->rs_std_ohm);
    r.rs_ohm = r.valid ? last_estimate_->rs_ohm : 0.0;
    r.rs_sigma_ohm = r.valid ? last_estimate_->rs_std_ohm : 0.0;
    r.rs0_ohm = controller_.calibration().rs0_ohm;
    r.estimate_count = estimate_count_;
    p.resistance = r;
  }
  // A calibration's start and end go out at once, not at the next 100 ms: a plant that follows
  // the Calibrating bit with an accelerated thermal time (pmsm-plant) would otherwise run up to
  // a publication interval times its acceleration out of step at each edge.
  p.calibrating_changed = tel.calibrating != calibrating_published_;
  if (due(thermal_every_) || p.calibrating_changed) {
    calibrating_published_ = tel.calibrating;
    protocol::ThermalEstimate t;
    t.valid = tel.thermal_valid && std::isfinite(tel.thermal.winding_C) && std::isfinite(tel.thermal.winding_std_C);
    t.winding_temp_C = t.valid ? tel.thermal.winding_C : 0.0;
    t.winding_temp_sigma_C = t.valid ? tel.thermal.winding_std_C : 0.0;
    t.magnet_valid = tel.magnet_valid && std::isfinite(tel.magnet_C) && std::isfinite(tel.magnet_std_C);
    t.magnet_temp_C = t.magnet_valid ? tel.magnet_C : 0.0;
    t.magnet_temp_sigma_C = t.magnet_valid ? tel.magnet_std_C : 0.0;
    t.calibrated = tel.calibrated;
    t.derating_active = tel.derating || tel.magnet_derating;  // either temperature (DRIVE_STATUS says which)
    t.stale = !last_estimate_s_ || now_s - *last_estimate_s_ > rates_.stale_after_s;
    t.calibration_result = to_protocol(tel.calibration_outcome);
    t.calibrating = tel.calibrating;
    p.thermal = t;
  }
  if (due(status_every_)) {
    protocol::DriveStatus s;
    s.state = to_protocol(st.state);
    unsigned reasons = 0U;
    reasons |= tel.derating ? unsigned{protocol::kLimitReasonWindingTemp} : 0U;
    reasons |= tel.magnet_derating ? unsigned{protocol::kLimitReasonMagnetTemp} : 0U;
    reasons |= tel.voltage_limited ? unsigned{protocol::kLimitReasonVoltage} : 0U;
    reasons |= tel.current_limited() ? unsigned{protocol::kLimitReasonCurrent} : 0U;
    reasons |= tel.speed_limited ? unsigned{protocol::kLimitReasonSpeed} : 0U;
    s.limiting_reasons = static_cast<std::uint8_t>(reasons);
    s.current_limit_A = tel.current_limit_A;
    s.time_to_limit_valid = tel.time_to_limit_valid;
    s.time_to_limit_s = tel.time_to_limit_valid ? tel.time_to_limit_s : 0.0;
    // The shaft as the drive last tracked it, while that is the present: a gap shorter than the
    // supervisor's sensor timeout (a lost sample, which the drive itself bridges) keeps the
    // reading; a longer one, or a latched fault (the controller sees no sample then), leaves
    // no value rather than the last speed of a shaft that may have stopped or been carried on.
    s.motion_valid = motion_known_until_ != 0U &&
                     period_ + advance_ - motion_known_until_ <
                         static_cast<std::uint64_t>(std::max(supervisor_.config().sensor_timeout_periods, 1));
    s.speed_rad_s = s.motion_valid ? tel.speed_m_rad_s : 0.0;
    if (s.motion_valid && torque_samples_ > 0U) {
      const double n = static_cast<double>(torque_samples_);
      s.torque_Nm = controller_.torque_estimate_Nm(torque_iq_sum_A_ / n, torque_idiq_sum_A2_ / n);
    } else {
      s.torque_Nm = s.motion_valid ? controller_.torque_estimate_Nm() : 0.0;
    }
    torque_iq_sum_A_ = 0.0;
    torque_idiq_sum_A2_ = 0.0;
    torque_samples_ = 0U;
    p.status = s;
  }
  if (due(heartbeat_every_)) {
    protocol::Heartbeat h;
    h.uptime_s = now_s;
    h.state = to_protocol(st.state);
    h.counter = heartbeat_counter_++;
    h.deadline_misses = in.deadline_misses;
    h.ambient_source = ambient_held_                   ? protocol::AmbientSource::kHeld
                       : sensed_ambient_C_.has_value() ? protocol::AmbientSource::kSensor
                                                       : protocol::AmbientSource::kConfigured;
    p.heartbeat = h;
  }
  publish_fault_changes(due(fault_every_));
}

void DriveNode::publish_fault_changes(bool repeat_due) noexcept {
  NodePublications& p = out_.publications;
  const std::uint32_t latched = supervisor_.status().latched_mask;
  const std::uint32_t changed = latched ^ published_latched_;
  p.fault_changed = changed != 0U;
  if (changed == 0U && !(repeat_due && latched != 0U)) {
    return;  // the common period: nothing latched, nothing changed (a scan of every code costs 240 instructions)
  }
  for (std::size_t k = 1; k < core::kFaultCodeCount; ++k) {
    const auto code = static_cast<core::FaultCode>(k);
    const std::uint32_t b = core::Supervisor::bit(code);
    const bool active = (latched & b) != 0U;
    if ((changed & b) != 0U) {
      fault_changed_s_[k] = uptime_s();
    }
    if ((changed & b) != 0U || (repeat_due && active)) {
      protocol::FaultReport& f = p.faults[p.fault_count++];
      f.code = static_cast<protocol::FaultCode>(k);
      f.active = active;
      f.occurrence_count = supervisor_.counts()[k];
      f.last_change_uptime_s = fault_changed_s_[k];
    }
  }
  published_latched_ = latched;
}

}  // namespace pmsm::app
