#include "publisher.hpp"

#include <cmath>
#include <numbers>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "calibration_file.hpp"
#include "pmsm/hal/codec.hpp"
#include "pmsm/hal/protocol_filters.hpp"

namespace pmsm::daemon {
namespace {

namespace protocol = hal::protocol;

std::string fault_name(protocol::FaultCode code) {
  for (const protocol::ValueLabel& l : protocol::kFaultCodeLabels) {
    if (l.value == static_cast<std::int64_t>(code)) {
      return std::string(l.label);
    }
  }
  return fmt::format("FAULT_{}", static_cast<int>(code));
}

std::uint64_t total_rejected(const LoopStats& s) {
  std::uint64_t n = 0;
  for (std::size_t i = 1; i < s.rejected.size(); ++i) {
    n += s.rejected[i];
  }
  return n;
}

std::string rejected_text(const LoopStats& now, const LoopStats& before) {
  std::string text;
  for (std::size_t i = 1; i < now.rejected.size(); ++i) {
    const std::uint64_t n = now.rejected[i] - before.rejected[i];
    if (n != 0U) {
      text += fmt::format("{}{} {}", text.empty() ? "" : ", ", protocol::to_string(static_cast<protocol::DecodeStatus>(i)), n);
    }
  }
  return text;
}

// The median and the 99th percentile bucket of the timing histogram, as "< N us".
std::string timing_text(const LoopStats& s) {
  std::uint64_t total = 0;
  for (const std::uint64_t n : s.timing_us) {
    total += n;
  }
  if (total == 0U) {
    return "no commands yet";
  }
  auto bucket_limit = [&](double q) {
    std::uint64_t seen = 0;
    for (std::size_t k = 0; k < s.timing_us.size(); ++k) {
      seen += s.timing_us[k];
      if (static_cast<double>(seen) >= q * static_cast<double>(total)) {
        return std::uint64_t{1} << k;
      }
    }
    return std::uint64_t{1} << (s.timing_us.size() - 1);
  };
  return fmt::format("sample->command median < {} us, p99 < {} us, max {:.0f} us", bucket_limit(0.5), bucket_limit(0.99),
                     static_cast<double>(s.max_step_ns) * 1e-3);
}

}  // namespace

Publisher::Publisher(const DaemonConfig& config, hal::CanBus& bus, DriveLoop& loop)
    : config_(config),
      bus_(bus),
      loop_(loop),
      node_(static_cast<protocol::NodeId>(config.can.node)),
      last_report_(std::chrono::steady_clock::now()) {
  const protocol::FilterSet own = protocol::published_filters(protocol::Role::kDaemon, node_);
  if (const hal::Status s = bus_.set_filters(own.view()); !s.ok()) {
    spdlog::warn("CAN interface '{}': cannot listen for another sender of node {}'s frames ({}): a second daemon "
                 "configured as node {} would go unnoticed",
                 config_.can.interface, config_.can.node, s.message(), config_.can.node);
  }
}

template <typename Message>
void Publisher::send(const Message& m) {
  hal::CanFrame frame{};
  const protocol::EncodeStatus e = protocol::encode(m, node_, frame);
  if (e != protocol::EncodeStatus::kOk && e != protocol::EncodeStatus::kSaturated) {
    ++stats_.frames_failed;
    return;
  }
  const hal::SendResult result = bus_.send(frame, std::chrono::milliseconds{2});
  if (result == hal::SendResult::kOk) {
    ++stats_.frames_sent;
    return;
  }
  ++stats_.frames_failed;
  if (result == hal::SendResult::kInterfaceDown) {
    reopen_if_due();
  }
}

void Publisher::reopen_if_due() {
  // An interface deleted and created again (a USB adapter replugged, `ip link del/add`) leaves
  // this socket unbound for good: every send fails until it is reopened. The control socket
  // has its own recovery (DriveLoop::recover_interface); this one is reopened here, at most once
  // a reopen interval, once the interface is up.
  const auto now = std::chrono::steady_clock::now();
  const auto interval = std::chrono::duration<double, std::milli>(config_.can.reopen_interval_ms);
  if (now - last_reopen_try_ < interval) {
    return;
  }
  last_reopen_try_ = now;
  if (!bus_.interface_up()) {
    return;
  }
  if (const hal::Status status = bus_.reopen(); status.ok()) {
    ++stats_.reopens;
    spdlog::warn("CAN interface '{}': the publishing socket reopened ({} time(s) so far)", config_.can.interface,
                 stats_.reopens);
  } else if (!reopen_failure_logged_) {
    reopen_failure_logged_ = true;
    spdlog::error("CAN interface '{}': cannot reopen the publishing socket: {} (tried again every {:g} ms)",
                  config_.can.interface, status.message(), config_.can.reopen_interval_ms);
    return;
  }
  reopen_failure_logged_ = false;
}

// What a fault's cause measured, against the key that set the limit, e.g. "DC bus 0.0 V, below
// supervisor.dc_bus_min_V (390 V): "; empty for the faults the caller reports.
std::string Publisher::fault_cause(protocol::FaultCode code, double value) const {
  const core::SupervisorConfig& c = config_.supervisor;
  switch (code) {
    case protocol::FaultCode::kDcBusUndervoltage:
      return fmt::format("DC bus {:.1f} V, below supervisor.dc_bus_min_V ({:g} V): ", value, c.dc_bus_min_V);
    case protocol::FaultCode::kDcBusOvervoltage:
      return fmt::format("DC bus {:.1f} V, above supervisor.dc_bus_max_V ({:g} V): ", value, c.dc_bus_max_V);
    case protocol::FaultCode::kOvercurrent:
      return fmt::format("a phase current of {:.1f} A, above supervisor.overcurrent_A ({:g} A): ", value, c.overcurrent_A);
    case protocol::FaultCode::kCurrentSum:
      return fmt::format("|ia + ib + ic| = {:.2f} A, above supervisor.current_sum_max_A ({:g} A; a phase-current sensor "
                         "is broken): ",
                         value, c.current_sum_max_A);
    case protocol::FaultCode::kCurrentOffset:
      return fmt::format("a phase current sensor read {:.2f} A with the gates off at power-up, further from zero than "
                         "supervisor.current_offset_max_A ({:g} A; a broken or stuck sensor; restart the daemon once it is "
                         "fixed): ",
                         value, c.current_offset_max_A);
    case protocol::FaultCode::kOutputFeedback:
      if (value < 0.0) {
        return fmt::format("the power stage reported its gates switching for {:.0f} samples in a row while the drive held "
                           "them off (supervisor.output_feedback_periods = {}; a stage that ignores the enable, or a stuck "
                           "OutputEnabled report; at power-up the drive measures its current offsets only with the gates "
                           "off): ",
                           -value, c.output_feedback_periods);
      }
      return fmt::format("the power stage reported its gates off for {:.0f} samples in a row while the drive enabled them "
                         "(supervisor.output_feedback_periods = {}; an open enable chain, a safe torque off, a fault of the "
                         "stage's own): ",
                         value, c.output_feedback_periods);
    case protocol::FaultCode::kAmbientImplausible:
      return fmt::format("the ambient sensor reads {:.1f} C, outside supervisor.ambient_min_C .. ambient_max_C ({:g} .. "
                         "{:g} C): ",
                         value, c.ambient_min_C, c.ambient_max_C);
    case protocol::FaultCode::kEncoderJump:
      if (value >= static_cast<double>(c.encoder_counts)) {
        return fmt::format("the encoder read a count of {:.0f}, beyond its {} a turn: ", value, c.encoder_counts);
      }
      return fmt::format("the encoder moved {:.0f} counts between two samples, more than supervisor.max_speed_rad_s "
                         "({:g} rad/s) allows: ",
                         value, c.max_speed_rad_s);
    case protocol::FaultCode::kOvertemperature:
      return fmt::format("winding estimate {:.1f} C, above supervisor.trip_temp_C ({:g} C): ", value, c.trip_temp_C);
    case protocol::FaultCode::kOverspeed:
      return fmt::format("the shaft at {:.1f} rad/s, above supervisor.overspeed_rad_s ({:g} rad/s): ", value, c.overspeed_rad_s);
    case protocol::FaultCode::kSensorTimeout:
      // The supervisor counts the loop's waits that ended without a sample, each can.sample_timeout_ms
      // of wall time (not control periods: a review found the log said 10 periods for a 20 ms gap).
      return fmt::format("no sample in {:.0f} waits of can.sample_timeout_ms ({:g} ms each, about {:g} ms; "
                         "supervisor.sensor_timeout_periods): ",
                         value, config_.can.sample_timeout_ms, value * config_.can.sample_timeout_ms);
    case protocol::FaultCode::kDuplicateNode: {
      std::string cause;
      if (foreign_.active || !second_source_.active) {
        cause = fmt::format("another device sends node {}'s frames (0x{:03X} last; can.node = {} on two daemons?)",
                            config_.can.node, foreign_id_, config_.can.node);
      }
      if (second_source_.active) {
        cause += fmt::format("{}SENSOR_SAMPLE frames from two sources on node {} (a second power stage as node {}?)",
                             cause.empty() ? "" : "; and ", config_.can.node, config_.can.node);
      }
      return cause + ": ";
    }
    case protocol::FaultCode::kHardwareOvercurrent:
      return "the power stage's own over-current comparator tripped (SENSOR_SAMPLE's HardwareOvercurrent flag: a "
             "short circuit, a phase to earth, or a current regulator far out of tune): ";
    case protocol::FaultCode::kBusOff:
      return fmt::format("the CAN controller of '{}' went bus-off (too many transmit errors: wiring, termination, bit "
                         "rate, or another node answering on the same identifiers); a stop command clears the fault once "
                         "the controller has restarted, after the interface's restart-ms (ip link set {} type can restart-ms 100) or by hand "
                         "(ip link set {} type can restart): ",
                         config_.can.interface, config_.can.interface, config_.can.interface);
    case protocol::FaultCode::kCommandTimeout:
      return fmt::format("no valid DRIVE_COMMAND for {:.3f} s, above supervisor.command_timeout_s ({:g} s): ", value,
                         c.command_timeout_s);
    default:
      return {};
  }
}

void Publisher::log_fault(const protocol::FaultReport& f, const PublicationRecord& r) {
  const std::uint32_t bit = 1U << static_cast<unsigned>(f.code);
  const bool was = (active_faults_ & bit) != 0U;
  if (f.active && !was) {
    spdlog::error("fault {}: {}the drive is in its safe state (gates off); {} time(s) since start", fault_name(f.code),
                  fault_cause(f.code, r.fault_values[static_cast<std::size_t>(f.code)]), f.occurrence_count);
    if (f.code == protocol::FaultCode::kPeriodMismatch) {
      spdlog::error("fault PERIOD_MISMATCH: the power stage samples every {:.2f} us (SENSOR_SAMPLE PwmPeriod), this "
                    "drive steps every {:.2f} us (controller.control.period_s = {:g} s): every clock of the drive would run at "
                    "the wrong rate; make the two configurations agree (for pmsm-plant, 1 / "
                    "inverter.pwm_frequency_Hz) and clear the fault",
                    r.reported_period_s * 1e6, config_.controller.drive.period_s * 1e6, config_.controller.drive.period_s);
    }
    active_faults_ |= bit;
  } else if (!f.active && was) {
    spdlog::info("fault {} cleared", fault_name(f.code));
    active_faults_ &= ~bit;
  }
}

void Publisher::log_refusals(const PublicationRecord& r) {
  if (r.estimates_gated != estimates_gated_logged_) {
    spdlog::warn("{} winding estimate(s) not fused: further than thermal.gate_sigma ({:g}) from the thermal filter's "
                 "prediction ({} in all; several in a row that agree restart the filter from them)",
                 r.estimates_gated - estimates_gated_logged_, config_.controller.drive.thermal.gate_sigma, r.estimates_gated);
    estimates_gated_logged_ = r.estimates_gated;
  }
  if (r.estimates_dropped_at_restart != estimates_dropped_logged_) {
    spdlog::info("{} winding estimate(s) dropped: dated after their event, they were waiting for their time when the "
                 "thermal filter restarted (a calibration or a restored state; {} in all)",
                 r.estimates_dropped_at_restart - estimates_dropped_logged_, r.estimates_dropped_at_restart);
    estimates_dropped_logged_ = r.estimates_dropped_at_restart;
  }
  if (r.magnet_rejected != magnet_rejected_logged_) {
    const std::uint32_t n = r.magnet_rejected - magnet_rejected_logged_;
    magnet_rejected_logged_ = r.magnet_rejected;
    switch (r.magnet_refusal.reason) {
      case core::MagnetRefusal::kImplausible:
        spdlog::warn("{} magnet (EMF) reading(s) refused, {} in all: the last read {:.1f} C, outside {:.0f}...{:.0f} C where no "
                     "magnet is; is Ke0 (calibration.ke0_V_s_per_rad, Eq. 3 form: phase peak V per mechanical rad/s) this "
                     "motor's?",
                     n, r.magnet_rejected, r.magnet_refusal.reading_C, core::kMagnetPlausibleMin_C, core::kMagnetPlausibleMax_C);
        break;
      case core::MagnetRefusal::kInconsistent:
        spdlog::warn("{} magnet (EMF) reading(s) refused, {} in all: the last read {:.1f} C, more than {:g} sigma from the "
                     "estimate {:.1f} C (sigma {:.1f} C, the reading's included)",
                     n, r.magnet_rejected, r.magnet_refusal.reading_C, core::kMagnetGateSigma, r.magnet_refusal.against_C,
                     r.magnet_refusal.against_std_C);
        break;
      default:
        spdlog::warn("{} magnet (EMF) reading(s) refused, {} in all: the last {}", n, r.magnet_rejected,
                     core::magnet_refusal_text(r.magnet_refusal.reason));
        break;
    }
  }
}

void Publisher::handle(const PublicationRecord& r) {
  // A calibration's events and pairs where it ended at its timeout on fewer than calibration.events.
  const auto cut_short_text = [this](const PublicationRecord& record) {
    return app::cut_short_calibration_text(record.calibration_events, config_.controller.drive.calibration_events,
                                           record.calibration_pairs, record.calibration_aborts,
                                           config_.controller.drive.estimator);
  };
  log_refusals(r);
  const app::NodePublications& p = r.publications;
  for (std::size_t k = 0; k < p.fault_count; ++k) {
    send(p.faults[k]);
    log_fault(p.faults[k], r);
  }
  if (p.status) {
    send(*p.status);
  }
  if (p.thermal) {
    send(*p.thermal);
    if (!first_thermal_logged_ && p.thermal->valid) {
      first_thermal_logged_ = true;
      spdlog::info("first THERMAL_ESTIMATE: winding {:.1f} +- {:.1f} C ({}); current sensors' noise {:.3f} A{}",
                   p.thermal->winding_temp_C, p.thermal->winding_temp_sigma_C,
                   p.thermal->calibrated ? "calibrated" : "nameplate Rs0", r.current_noise_A,
                   config_.controller.sensors.current_noise_A ? " (configured)" : " (measured with the offsets)");
    }
  }
  if (p.resistance) {
    send(*p.resistance);
  }
  if (p.injection) {
    send(*p.injection);
    // A method picked at run time (INJECTION_COMMAND) that misleads on a machine configured as
    // salient: said once per method, with its first report, as the configured one was at start.
    // (Reports come only from the scheduler, which runs only with estimator.kind = "injection".)
    static_assert(static_cast<unsigned>(hal::protocol::InjectionMethod::kDc) < 32U);
    const unsigned bit = 1U << static_cast<unsigned>(p.injection->method);
    if ((salient_method_warned_ & bit) == 0U) {
      salient_method_warned_ |= bit;
      const core::InjectionConfig& configured = config_.controller.drive.injection;
      if (p.injection->method != app::protocol_method(configured.method, configured.separation)) {
        const app::CoreInjectionMethod m = app::core_injection_method(p.injection->method);
        if (const std::string w = app::salient_method_warning(config_.controller.drive, m.method, m.separation);
            !w.empty()) {
          spdlog::warn("injection method changed by an INJECTION_COMMAND: {}", w);
        }
      }
    }
    // Pairs mostly rejected as speed or load changes: why the drive measures rarely. Judged over
    // windows of kPairJudgedWindow pairs judged (recorded to their end, as the advice counts
    // them: a drive near its limits reports many skips between two judged pairs), so that a duty
    // cycle that changes later is judged afresh; said once.
    if (const auto result = static_cast<std::size_t>(p.injection->result);
        !pair_rejection_advised_ && result < pair_results_.size()) {
      ++pair_results_[result];
      if (core::pair_judged(static_cast<core::PairOutcome>(result)) && ++pair_window_judged_ >= kPairJudgedWindow) {
        if (const std::string advice = app::pair_rejection_advice(pair_results_, config_.controller.drive);
            !advice.empty()) {
          pair_rejection_advised_ = true;
          spdlog::warn("{} (said once)", advice);
        }
        pair_results_ = {};
        pair_window_judged_ = 0;
      }
    }
  }
  if (p.heartbeat) {
    send(*p.heartbeat);
    send_receive_status(loop_.stats());
  }
  if (r.timing) {
    send(*r.timing);
  }
  if (r.thermal_state) {
    store_thermal_state(*r.thermal_state, r.ambient_C);
  }
  if (r.restore_ambient_shift_C != 0.0 && !restore_shift_logged_) {
    restore_shift_logged_ = true;
    spdlog::info("thermal state: the ambient reads {:.1f} C at this start, not the stored ambient its cooling assumed "
                 "(above): the restored winding moved {:+.1f} K to the middle of the coolings towards the two, its band "
                 "widened to cover either",
                 r.ambient_C, r.restore_ambient_shift_C);
  }
  // Dropouts that began and ended between two records: the held flag never showed them.
  const std::uint32_t dropouts = r.ambient_dropouts - ambient_dropouts_;
  ambient_dropouts_ = r.ambient_dropouts;
  const std::uint32_t shown = r.ambient_held && !ambient_held_ ? 1U : 0U;
  if (dropouts > shown) {
    spdlog::warn("the ambient sensor stopped reporting briefly {} time(s) since the last report (SENSOR_SAMPLE "
                 "AmbientValid = 0; the drive held its last reading meanwhile): a loose connector or a sensor at "
                 "the edge of its range? {} dropout(s) since start",
                 dropouts - shown, r.ambient_dropouts);
  }
  if (r.ambient_held != ambient_held_) {
    ambient_held_ = r.ambient_held;
    if (r.ambient_held) {
      spdlog::warn("the ambient sensor stopped reporting (SENSOR_SAMPLE AmbientValid = 0): the drive holds its last "
                   "reading, {:.1f} C, for the thermal model (a calibration at the ambient is refused meanwhile)",
                   r.ambient_C);
    } else if (r.ambient_sensed) {
      spdlog::info("the ambient sensor reports again: {:.1f} C", r.ambient_C);
    } else {
      spdlog::warn("the held ambient reading dropped with a new power stage (another PWM period reported): the drive "
                   "assumes {:.1f} C until a sensor reports",
                   r.ambient_C);
    }
  }
  if (r.angle_check) {
    // The calibration's rotor-angle check ended: the offset it found and whether it corrected it.
    const core::AngleCheckResult& a = *r.angle_check;
    constexpr double kDeg = 180.0 / std::numbers::pi;
    if (a.outcome == core::AngleCheckOutcome::kMeasured) {
      spdlog::info("calibration: rotor-angle check found {:+.3f} deg electrical (+- {:.3f} levels, +- {:.3f} the "
                   "speed's noise, +- {:.3f} saliency model); correction of sensors.encoder_offset_rad in use {:+.3f} deg",
                   a.offset_rad * kDeg, a.offset_std_rad * kDeg, a.speed_std_rad * kDeg, a.model_std_rad * kDeg,
                   r.angle_correction_rad * kDeg);
    } else if (a.outcome == core::AngleCheckOutcome::kOutOfRange) {
      spdlog::error("calibration: rotor-angle check found the angle {:+.1f} deg electrical off, more than "
                    "calibration.angle_check_max_offset_rad corrects: commission sensors.encoder_offset_rad (or check the "
                    "phase order and motor.pole_pairs); the calibration is refused",
                    a.offset_rad * kDeg);
    } else if (r.angle_check_pending) {
      spdlog::warn("calibration: rotor-angle check {}: it starts again once the drive has run {:.2f} s without a stop",
                   core::to_string(a.outcome), core::DriveController::kSweepHoldoff_s);
    } else {
      spdlog::warn("calibration: rotor-angle check {}: the angle in use (correction {:+.3f} deg) holds for this calibration",
                   core::to_string(a.outcome), r.angle_correction_rad * kDeg);
    }
  }
  if (r.inverter_sweep) {
    // The calibration's bridge sweep ended: what it measured, or why not (a calibration without
    // it keeps the configured band and the Vx prior, and its Rs0 depends on them).
    const core::InverterSweepResult& w = *r.inverter_sweep;
    if (w.outcome == core::InverterSweepOutcome::kMeasured) {
      spdlog::info("calibration: bridge sweep measured Vx {:.3f} +- {:.3f} V, band {:.3f} A", w.vx_V, w.vx_std_V,
                   w.band_A);
    } else {
      // What a fit that was not used read, where the levels were fitted (an unresolved fit's Vx
      // error bar is the reason itself; an implausible one's sign).
      const std::string fit =
          w.fitted ? fmt::format(" (its fit: Vx {:.3f} +- {:.3f} V, band {:.3f} A)", w.vx_V, w.vx_std_V, w.band_A) : "";
      if (r.inverter_sweep_pending) {
        spdlog::warn("calibration: bridge sweep {}{}: it starts again once the drive has run {:.2f} s without a stop",
                     core::to_string(w.outcome), fit, core::DriveController::kSweepHoldoff_s);
      } else {
        spdlog::warn("calibration: bridge sweep {}{}: the bridge's band is not measured, the configured band "
                     "(control.dead_time_band_A) and the Vx prior hold for this calibration",
                     core::to_string(w.outcome), fit);
      }
    }
  }
  if (r.calibration_failed) {
    if (r.calibration_failure == core::CalibrationFailure::kAngleOffset) {
      spdlog::warn("calibration refused: the rotor angle is off by more than the check corrects (above); the previous "
                   "calibration stays in use");
    } else if (r.calibration_failure == core::CalibrationFailure::kWindingWarm) {
      spdlog::warn("calibration refused: the winding is {:.1f} C above the ambient sensor's temperature ({}): "
                   "Rs0 would be referred to a temperature the winding is "
                   "not at; let the motor cool to the ambient, or give the winding's temperature with the request. A motor "
                   "replaced or rewound since the calibration in use reads warm through that calibration's Rs0 even when "
                   "cold: give its temperature with the request, or remove the stored calibration. The previous "
                   "calibration stays in use",
                   r.calibration_winding_rise_C, app::kWindingWarmMeasure);
    } else if (r.calibration_failure == core::CalibrationFailure::kAmbientHeld) {
      spdlog::warn("calibration refused: the ambient sensor (SENSOR_SAMPLE AmbientTemp) stopped reporting and its last "
                   "reading, {:.1f} C, of unknown age, stands for it: Rs0 referred to it would carry its error into every "
                   "later estimate. Mend the sensor, or give the winding's temperature with the request. The previous "
                   "calibration stays in use",
                   r.ambient_C);
    } else if (r.calibration_failure == core::CalibrationFailure::kTemperatureImplausible) {
      spdlog::warn("calibration refused: the temperature given with the request lies {:.1f} K {} the winding the drive "
                   "measured within the last minute (more than 4 sigma + calibration.max_winding_rise_C): Rs0 referred to "
                   "it would put every later estimate off by about as much. Check the reading (the winding's, at rest), or "
                   "calibrate on the ambient sensor after a cool-down. The previous calibration stays in use",
                   std::abs(r.calibration_winding_rise_C), r.calibration_winding_rise_C > 0.0 ? "below" : "above");
    } else if (r.calibration_failure == core::CalibrationFailure::kCableTakesAll) {
      spdlog::warn("calibration refused: Rs0 {:.5f} ohm, the whole resistance the drive measured, is not above the motor "
                   "cable's resistance (motor.cable_resistance_ohm = {} ohm at 20 C): Eq. 1 would have no winding left. "
                   "Check the cable's resistance and the window (injection.rs_min_ohm); the previous calibration stays "
                   "in use",
                   r.calibration_rs0_ohm, config_.controller.drive.thermal.cable_resistance_20C_ohm);
    } else if (r.calibration_failure == core::CalibrationFailure::kOvertemperatureLatched) {
      spdlog::warn("calibration refused: OVERTEMPERATURE is latched, and a calibration would start the thermal estimate "
                   "again from the temperature it is given, so that the trip could clear with the winding still hot. Let "
                   "the motor cool until a stop command clears the trip, then ask again. The previous calibration stays "
                   "in use");
    } else if (r.calibration_failure == core::CalibrationFailure::kRsOutsideWindow) {
      spdlog::warn("calibration refused: {} The previous calibration stays in use",
                   app::rs_outside_window_text(config_.controller.drive, r.calibration_rs0_ohm, r.calibration_rs0_std_ohm));
    } else if (r.calibration_failure == core::CalibrationFailure::kUncertain) {
      const std::string cut_short = cut_short_text(r);
      spdlog::warn("calibration refused: Rs0 {:.5f} +- {:.5f} ohm{} is less certain than "
                   "calibration.max_rs0_std_fraction allows ({}); the previous calibration stays in use",
                   r.calibration_rs0_ohm, r.calibration_rs0_std_ohm, cut_short,
                   app::uncertain_calibration_advice(!cut_short.empty(), config_.controller.drive.estimator));
    } else {
      spdlog::warn("calibration gave up (calibration.timeout_s, {:.0f} s, with fewer published events than "
                   "calibration.min_events{}: {}); the previous calibration stays in use",
                   config_.controller.drive.calibration_timeout_s,
                   app::calibration_pairs_text(config_.controller.drive.estimator, r.calibration_pairs, r.calibration_aborts),
                   app::calibration_timeout_advice(config_.controller.drive.estimator));
    }
  }
  if (r.calibration_to_store) {
    const core::Calibration& c = *r.calibration_to_store;
    // Ke0 in Eq. 3's form (phase peak volts per mechanical rad/s), and in motor.ke_V_s_per_rad's
    // (line-to-line RMS: x sqrt(3/2)), so that it compares with the nameplate.
    if (const std::string cut_short = cut_short_text(r); !cut_short.empty()) {
      spdlog::warn("calibration completed{}: its Rs0 is less certain than a whole run's; calibrate again unloaded at a "
                   "steady speed when the machine allows",
                   cut_short);
    }
    spdlog::info("calibration done: Rs0 {:.5f} ohm at {:.1f} C{}, Ke0 {:.4f} V s/rad phase peak ({:.4f} line-to-line RMS, "
                 "the form of motor.ke_V_s_per_rad), {}, {}",
                 c.rs0_ohm, c.t0_C, app::t0_rise_text(c), c.ke0_V_s_per_rad, c.ke0_V_s_per_rad * std::sqrt(1.5),
                 c.dead_time_band_A > 0.0 ? fmt::format("bridge band {:.3f} A (swept)", c.dead_time_band_A)
                                          : std::string("bridge band not measured (the configured one holds)"),
                 c.vx_std_V > 0.0 ? fmt::format("bridge voltage Vx {:.3f} +- {:.3f} V", c.vx_V, c.vx_std_V)
                                  : std::string("bridge voltage not learned (the configured prior holds)"));
    if (const std::string w = app::rs0_off_nameplate_warning(config_.controller.drive, c); !w.empty()) {
      spdlog::warn("{}", w);
    }
    if (const std::string w = app::ke0_off_motor_warning(config_.controller.drive, c); !w.empty()) {
      spdlog::warn("{}", w);
    }
    store_calibration(c);
  }
  if (r.magnet_reference_to_store) {
    const core::Calibration& c = *r.magnet_reference_to_store;
    spdlog::info("magnet reference taken: Ke0 {:.4f} +- {:.4f} V s/rad phase peak at {:.1f} C ({:.4f} line-to-line "
                 "RMS), from {} turning events with the rotor taken at {:.1f} +- {:.1f} C (between the ambient and "
                 "the housing's estimate); the calibration ran at rest and measured none; magnet temperatures from now on",
                 c.ke0_V_s_per_rad, c.ke0_std_V_s_per_rad, c.t0_C, c.ke0_V_s_per_rad * std::sqrt(1.5),
                 r.magnet_reference_events, r.magnet_reference_at_C, r.magnet_reference_std_C);
    if (const std::string w = app::ke0_off_motor_warning(config_.controller.drive, c); !w.empty()) {
      spdlog::warn("{}", w);
    }
    store_calibration(c);
  }
}

void Publisher::store_calibration(const core::Calibration& c) {
  if (config_.controller.calibration_file.empty()) {
    return;
  }
  try {
    app::write_calibration_file(config_.controller.calibration_file, c, config_.source.filename().string(),
                                stored_axis(config_));
    ++stats_.calibrations_stored;
    spdlog::info("calibration stored in {}", config_.controller.calibration_file);
  } catch (const app::CalibrationFileNotDurable& e) {
    ++stats_.calibrations_stored;
    spdlog::warn("calibration stored, but not flushed to the disk: {}", e.what());
  } catch (const app::CalibrationFileError& e) {
    ++stats_.calibration_store_failures;
    spdlog::error("cannot store the calibration: {} (it is used until the daemon stops)", e.what());
  }
}

void Publisher::send_receive_status(const LoopStats& s) {
  using protocol::DecodeStatus;
  auto n = [&](DecodeStatus d) { return s.rejected[static_cast<std::size_t>(d)]; };
  protocol::ReceiveStatus m;
  m.last_rejection = static_cast<std::uint8_t>(s.last_rejection);
  m.last_rejected_id = static_cast<std::uint16_t>(s.last_rejected_id);
  m.commands_accepted = s.commands_accepted[0] + s.commands_accepted[1] + s.commands_accepted[2];
  m.rejected_crc = n(DecodeStatus::kBadCrc);
  m.rejected_counter = n(DecodeStatus::kRepeatedCounter) + n(DecodeStatus::kCounterJump);
  m.rejected_range = n(DecodeStatus::kOutOfRange);
  m.rejected_format = n(DecodeStatus::kWrongLength) + n(DecodeStatus::kWrongFrameFormat);
  m.rejected_other = n(DecodeStatus::kUnknownId) + n(DecodeStatus::kWrongNode) + n(DecodeStatus::kStreamDisturbed);
  send(m);
  rejected_sent_ = total_rejected(s);
  receive_status_sent_ = std::chrono::steady_clock::now();
}

void Publisher::store_thermal_state(const core::ThermalState& state, double ambient_C) {
  const std::string& path = config_.controller.thermal_state_file;
  if (path.empty()) {
    return;
  }
  app::StoredThermalState stored;
  stored.state = state;
  stored.ambient_C = ambient_C;
  stored.saved_unix_s =
      std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
  stored.axis = stored_axis(config_);
  try {
    app::write_thermal_state_file(path, stored);
    ++stats_.thermal_states_stored;
  } catch (const app::CalibrationFileNotDurable& e) {
    ++stats_.thermal_states_stored;
    if (!not_durable_logged_) {  // logged once: it would repeat every 10 s
      not_durable_logged_ = true;
      spdlog::warn("thermal state stored, but not flushed to the disk: {}", e.what());
    }
  } catch (const app::CalibrationFileError& e) {
    if (stats_.thermal_state_store_failures++ == 0) {  // logged once: it repeats every 10 s
      spdlog::error("cannot store the thermal state: {} (a restart will start the filter from the ambient sensor)", e.what());
    }
  }
}

void Publisher::after_batch() {
  const auto now = std::chrono::steady_clock::now();
  watch_for_duplicates(now);
  // Rejections are on the bus within 100 ms, not only with the next heartbeat.
  if (now - receive_status_sent_ >= std::chrono::milliseconds{100}) {
    if (const LoopStats s = loop_.stats(); total_rejected(s) != rejected_sent_) {
      send_receive_status(s);
    }
  }
  if (now - last_report_ < std::chrono::seconds{1}) {
    return;
  }
  last_report_ = now;
  report();
}

// Every 20 ms at most (a read that finds nothing is a system call): whatever arrived on the
// publishing endpoint is a frame another device sent on this node's published identifiers.
void Publisher::watch_for_duplicates(std::chrono::steady_clock::time_point now) {
  if (now - duplicates_watched_ < std::chrono::milliseconds{20}) {
    return;
  }
  duplicates_watched_ = now;
  bool heard = false;
  hal::ReceivedFrame f;
  // Bounded: a flood on these identifiers cannot hold the drain thread.
  for (int k = 0; k < 256 && bus_.receive(f, std::chrono::nanoseconds{0}) == hal::ReceiveStatus::kFrame; ++k) {
    if (f.frame.error) {
      continue;
    }
    ++stats_.foreign_frames;
    foreign_id_ = f.frame.id;
    heard = true;
  }
  if (heard) {
    if (foreign_.hear(now)) {
      const protocol::MessageDef* m = protocol::find_message(foreign_id_);
      spdlog::error("another device sends node {}'s {} (0x{:03X}) on '{}': a second pmsm-thermald configured as node {}? "
                    "Two drives would answer one power stage: fault DUPLICATE_NODE, gates off, until no other sender has "
                    "been heard for {:g} s and a stop command clears it. Give every axis its own can.node",
                    config_.can.node, m != nullptr ? m->name : std::string_view{"frame"}, foreign_id_,
                    config_.can.interface, config_.can.node,
                    std::chrono::duration<double>(kDuplicateHold).count());
    }
  } else if (foreign_.expire(now)) {
    spdlog::info("no other sender of node {}'s frames for {:g} s ({} frame(s) heard in all)", config_.can.node,
                 std::chrono::duration<double>(kDuplicateHold).count(), stats_.foreign_frames);
  }
  watch_sample_sources(now);
  if (const bool duplicate = foreign_.active || second_source_.active; duplicate != duplicate_) {
    duplicate_ = duplicate;
    loop_.set_duplicate_node(duplicate);
    if (!duplicate) {
      spdlog::info("DUPLICATE_NODE's cause is gone: a stop command clears the fault");
    }
  }
}

// A second (free-running) power stage configured as this node sends SENSOR_SAMPLE frames with its
// own count: the loop uses whichever count is ahead and drops the other's as older than the
// last one used (DriveLoop::on_frame), so the drive would control one stage from the other's
// sensors while both apply its commands. Dropped samples at a sustained rate say so.
void Publisher::watch_sample_sources(std::chrono::steady_clock::time_point now) {
  if (const auto elapsed = now - sample_window_start_; elapsed >= kSampleSourceWindow) {
    const LoopStats s = loop_.stats();
    const std::uint64_t stale = s.stale_samples - stale_at_window_start_;
    const std::uint64_t used = s.samples - samples_at_window_start_;
    sample_window_start_ = now;
    stale_at_window_start_ = s.stale_samples;
    samples_at_window_start_ = s.samples;
    // Judged as a rate (kSecondSourceMinStale per kSampleSourceWindow), so that a window the
    // drain thread stretched (a file's fsync, a slow journal) makes no trickle a second source.
    if (static_cast<double>(stale) * std::chrono::duration<double>(kSampleSourceWindow).count() >=
        static_cast<double>(kSecondSourceMinStale) * std::chrono::duration<double>(elapsed).count()) {
      if (second_source_.hear(now)) {
        spdlog::error("SENSOR_SAMPLE frames from two sources on node {} on '{}': {} in the last {:.0f} ms were older than "
                      "the samples the drive used ({} used): a second power stage configured as node {}, or a gateway "
                      "repeating its frames? The drive cannot tell which stage it controls: fault DUPLICATE_NODE, gates "
                      "off, until the second source has been quiet for {:g} s and a stop command clears it",
                      config_.can.node, config_.can.interface, stale,
                      std::chrono::duration<double, std::milli>(elapsed).count(), used, config_.can.node,
                      std::chrono::duration<double>(kDuplicateHold).count());
      }
      return;
    }
  }
  if (second_source_.expire(now)) {
    spdlog::info("no second source of node {}'s SENSOR_SAMPLE frames for {:g} s", config_.can.node,
                 std::chrono::duration<double>(kDuplicateHold).count());
  }
}

void Publisher::report() {
  const LoopStats s = loop_.stats();
  const LoopStats& p = last_;
  if (s.interface_down && !p.interface_down) {
    spdlog::error("CAN interface '{}' is down or gone: the drive is in its safe state; reopening every {} ms",
                  config_.can.interface, config_.can.reopen_interval_ms);
  } else if (!s.interface_down && s.reopens != p.reopens) {
    spdlog::warn("CAN interface '{}' is back: socket reopened ({} time(s) so far)", config_.can.interface, s.reopens);
  }
  if (const std::string text = rejected_text(s, p); !text.empty()) {
    spdlog::warn("rejected frames since the last report: {}", text);
  }
  if (const auto held = s.rejected[static_cast<std::size_t>(protocol::DecodeStatus::kStreamDisturbed)] -
                        p.rejected[static_cast<std::size_t>(protocol::DecodeStatus::kStreamDisturbed)];
      held != 0U) {
    spdlog::warn("{} command(s) for node {} passed their CRC and alive counter but were not acted on: frames with a bad CRC, "
                 "length or format came on the same command ID just before (two within {:g} s), so these may be garbage "
                 "that passed by chance (a device babbling on this node's command IDs?). A stop, or a repeat of the last "
                 "drive command acted on, is heard meanwhile; the rest again {:g} s after the failures",
                 held, config_.can.node, std::chrono::duration<double>(protocol::kDisturbedWindow).count(),
                 std::chrono::duration<double>(protocol::kDisturbedWindow).count());
  }
  if (s.stale_samples != p.stale_samples) {
    spdlog::warn("{} SENSOR_SAMPLE frame(s) older than the last one used dropped since the last report (a second power stage "
                 "or plant on node {}'s identifiers? a replaying gateway?)",
                 s.stale_samples - p.stale_samples, config_.can.node);
  }
  if (s.deadline_misses != p.deadline_misses) {
    spdlog::warn("{} deadline miss(es) since the last report (sample->command longer than one period); {}",
                 s.deadline_misses - p.deadline_misses, timing_text(s));
  }
  if (s.tx_dropped != p.tx_dropped || s.tx_failures != p.tx_failures || s.rx_errors != p.rx_errors ||
      s.rx_overflow != p.rx_overflow) {
    spdlog::warn("CAN I/O since the last report: {} command(s) dropped (queue full), {} failed send(s), {} failed read(s), "
                 "{} frame(s) dropped by the kernel before the control loop read them (its receive buffer full)",
                 s.tx_dropped - p.tx_dropped, s.tx_failures - p.tx_failures, s.rx_errors - p.rx_errors,
                 s.rx_overflow - p.rx_overflow);
  }
  if (s.publications_dropped != p.publications_dropped) {
    spdlog::warn("{} publication record(s) dropped: this thread did not keep up with the control loop",
                 s.publications_dropped - p.publications_dropped);
  }
  if (s.events_held != p.events_held) {
    spdlog::warn("{} event record(s) (fault reports, a calibration's end) waited in the control loop's "
                 "backlog: this thread did not keep up; they are published late, in order",
                 s.events_held - p.events_held);
  }
  if (s.events_lost != p.events_lost) {
    spdlog::error("{} event record(s) lost: the control loop's backlog of {} was full too (fault reports, or a "
                  "calibration's end that was then not stored)",
                  s.events_lost - p.events_lost, DriveLoop::kBacklogRecords);
  }
  if (p.samples == 0U && s.samples != 0U) {
    spdlog::info("sensor samples arriving: the control loop is running ({})", timing_text(s));
  }
  last_ = s;
}

std::string Publisher::summary() const {
  const LoopStats s = loop_.stats();
  const std::uint64_t rejected = total_rejected(s);
  return fmt::format(
      "periods {}, samples {} (re-sent {}, missing {}, skipped {}, stale {}), commands sent {}, accepted drive/injection/calibration commands "
      "{}/{}/{}, rejected frames {} ({}), deadline misses {}, {}, frames published {} (failed {}), publication records "
      "dropped {} (events held {}, lost {}), calibrations stored {}, "
      "interface losses {} (publishing socket reopened {}), CAN I/O: commands dropped {} (queue full), failed sends {}, "
      "failed reads {}, frames dropped on receive {}, frames of this node sent by another device {}, frames dated by their "
      "receive timestamp alone {} (found late and read again {})",
      s.periods, s.samples, s.resent_samples, s.missing_samples, s.skipped_samples, s.stale_samples, s.commands_sent, s.commands_accepted[0], s.commands_accepted[1],
      s.commands_accepted[2], rejected, rejected == 0U ? std::string("none") : rejected_text(s, LoopStats{}), s.deadline_misses,
      timing_text(s), stats_.frames_sent, stats_.frames_failed, s.publications_dropped, s.events_held, s.events_lost,
      stats_.calibrations_stored, s.interface_losses,
      stats_.reopens, s.tx_dropped, s.tx_failures, s.rx_errors, s.rx_overflow, stats_.foreign_frames,
      s.stamp_dated_frames, s.stamp_dated_late);
}

}  // namespace pmsm::daemon
