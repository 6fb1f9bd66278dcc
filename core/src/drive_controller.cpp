#include "pmsm/core/drive_controller.hpp"

#include <algorithm>
#include <cmath>
#include <utility>

#include "pmsm/core/machine_equations.hpp"

namespace pmsm::core {
namespace {

// The phase-current sign pattern in the rotor frame, averaged over a period in which the
// currents moved from i0 to i1: the direction of the voltage the bridge loses to dead time
// and device drop (per volt of per-phase error), see pair_estimator.hpp.
// With it, the first moment of the same signs over the period (soft_sign_moment), which the
// period's mean current needs (period_mean_current).
struct PeriodPattern {
  Dq mean;
  Dq moment;
};
// One phase's mean sign over the period and whether it varies in it. A phase whose line stays
// beyond the band and the noise correction's reach (kNoiseCorrectionReachSigma) on one side, as most phases
// do in most periods, is told by two compares: the same values mean_soft_sign_of_measured and
// soft_sign_varies give there, without their repeated tests.
struct PhaseSign {
  double mean = 0.0;
  bool varies = false;
};
// A phase whose current crosses or nears zero within the period (the rare case: out of line).
[[gnu::noinline]] PhaseSign phase_sign_near_zero(double i0, double i1, double band_A, double b, double noise_eff_A) {
  return {mean_soft_sign_of_measured(i0, i1, band_A, noise_eff_A), soft_sign_varies(i0, i1, b)};
}

// Beyond +-edge (the band and the noise's reach) at both ends the sign is constant; tested
// inline, since in most periods every phase is there.
inline PhaseSign phase_sign(double i0, double i1, double edge, double band_A, double b, double noise_eff_A) {
  if (i0 > edge && i1 > edge) {
    return {1.0, false};
  }
  if (i0 < -edge && i1 < -edge) {
    return {-1.0, false};
  }
  return phase_sign_near_zero(i0, i1, band_A, b, noise_eff_A);
}

PeriodPattern dead_time_pattern(const Abc& i0, const Abc& i1, double band_A, double noise_eff_A, const Rotation& r) {
  const double b = std::max(band_A, 0.0);
  const double reach = noise_eff_A > 0.0 && band_A > 0.0 ? kNoiseCorrectionReachSigma * noise_eff_A : 0.0;
  const double edge = b + reach;  // -edge is -b - reach exactly (rounding is symmetric)
  const PhaseSign pa = phase_sign(i0.a, i1.a, edge, band_A, b, noise_eff_A);
  const PhaseSign pb = phase_sign(i0.b, i1.b, edge, band_A, b, noise_eff_A);
  const PhaseSign pc = phase_sign(i0.c, i1.c, edge, band_A, b, noise_eff_A);
  const Dq mean = park(clarke(Abc{pa.mean, pb.mean, pc.mean}), r.c, r.s);
  // A phase whose current stays outside the band on one side has a constant sign and no
  // moment: in most periods no phase is near zero, and the moment is not computed at all.
  if (!(pa.varies || pb.varies || pc.varies)) {
    return {mean, Dq{}};
  }
  const Abc moment{pa.varies ? soft_sign_moment(i0.a, i1.a, b) : 0.0, pb.varies ? soft_sign_moment(i0.b, i1.b, b) : 0.0,
                   pc.varies ? soft_sign_moment(i0.c, i1.c, b) : 0.0};
  return {mean, park(clarke(moment), r.c, r.s)};
}

}  // namespace

bool controllable(const DriveInput& in) noexcept {
  // Every reading finite, in one test: the sum of the readings is inf or NaN when any one is
  // (inf - inf is NaN), and s - s is 0 for a finite s and NaN otherwise (four isfinite calls
  // cost the step about 20 instructions). Finite readings whose sum overflows (beyond 1e308 A
  // or V) are no readings either.
  const double sum = in.i_A.a + in.i_A.b + in.i_A.c + in.vdc_V;
  return in.valid && sum - sum == 0.0 && in.vdc_V > 0.0;
}

DriveController::DriveController(const DriveConfig& config)
    : config_(with_motor_derived(config)),
      kt_dq_Nm_per_A_(1.5 * config_.motor.pole_pairs * config_.current.flux_linkage_Wb),
      speed_limit_rad_s_(config_.speed_limit_rad_s > 0.0 ? config_.speed_limit_rad_s
                                                         : std::numeric_limits<double>::infinity()),
      thermal_update_periods_(static_cast<std::uint32_t>(
          std::max(1.0, std::round(config_.thermal_update_s / config_.period_s)))),
      speed_limit_gain_Nm_s_(config_.speed.inertia_kg_m2 *
                             std::min(5.0 * config_.speed.bandwidth_rad_s, 0.5 * config_.angle.pll_bandwidth_rad_s)),
      angle_(config_.angle),
      current_(config_.current),
      field_weakening_(config_.field_weakening),
      speed_(config_.speed),
      scheduler_(config_.injection, config_.period_s, config_.recording_capacity),
      baseline_(config_.baseline),
      observer_(config_.thermal, config_.calibration, config_.calibration.t0_C, false),
      derating_{config_.derating.max_current_A, false},
      injection_current_limit_A_(config_.derating.max_current_A) {
  field_weakening_.set_machine(config_.current.ld_H, config_.current.flux_linkage_Wb, config_.period_s);
  // The motoring voltage's filter (track_motoring_voltage): 20 ms takes the sensors' noise in
  // the loop's command down about fourteen times and the EMF harmonics' ripple (six a turn)
  // more than fifty times at 500 electrical rad/s, and follows a speed ramp within a few
  // per cent of the ramp's voltage over a second.
  constexpr double kMotoringVoltageFilter_s = 0.02;
  motoring_voltage_gain_ = std::min(config_.period_s / kMotoringVoltageFilter_s, 1.0);
  motoring_voltage_settle_periods_ = static_cast<std::uint32_t>(std::ceil(3.0 / motoring_voltage_gain_));
  held_on_limit_periods_ = static_cast<std::uint32_t>(std::max(1.0, std::ceil(kHeldOnLimit_s / config_.period_s - 1e-9)));
  // A command on the voltage limit can put a duty near a rail (pulse_lost) only on a bus with
  // Vdc (1 - f - 2 (1 + kPulseDeadTimeMargin) fraction) < 2 drop: below 2 drop / room, or on any bus when room
  // is not positive (the dead time, the drop and the period do not change).
  {
    dead_time_fraction_ = std::abs(config_.dead_time.dead_time_s / config_.period_s);
    const double room = (1.0 - config_.current.voltage_limit_fraction) -
                        2.0 * (1.0 + kPulseDeadTimeMargin) * dead_time_fraction_;
    pulse_check_below_V_ = room > 0.0 ? 2.0 * std::abs(config_.dead_time.device_drop_V) / room
                                      : std::numeric_limits<double>::infinity();
  }
  if (config_.vx_reference_bus_V > 0.0 && std::isfinite(config_.vx_reference_bus_V)) {
    vx_bus_slope_ = config_.dead_time.dead_time_s / config_.period_s;
    vx_referred_to_bus_ = true;
  }
  // DRIVE_STATUS reads the limit before the first thermal update sets it.
  telemetry_.current_limit_A = derating_.current_limit_A;
  // A stored calibration that measured the bridge replaces the configured band.
  band_measured_ = config_.calibration.dead_time_band_A > 0.0;
  use_band(band_measured_ ? config_.calibration.dead_time_band_A : config_.dead_time.current_band_A);
  // ... and one that checked the rotor angle corrects the commissioned offset.
  // (A non-finite one is no correction: the loaders refuse it, a configuration built in code
  // must not put NaN into every angle.)
  if (config_.calibration.angle_correction_measured && std::isfinite(config_.calibration.angle_correction_rad)) {
    angle_.set_offset_correction_rad(config_.calibration.angle_correction_rad);
    angle_measured_ = true;
  }
  // ... and one that learned the bridge's voltage gives the estimator's Vx prior (Rs0 was
  // learned with it: the two belong together), in place of the configured guess.
  if (config_.injection.fit_dead_time && config_.calibration.vx_std_V > 0.0 && std::isfinite(config_.calibration.vx_std_V) &&
      std::isfinite(config_.calibration.vx_V)) {
    // At the bus it was learned on (none stored: the reference bus, where the slope adds nothing).
    const bool at_bus = vx_referred_to_bus_ && config_.calibration.vx_bus_V > 0.0 && std::isfinite(config_.calibration.vx_bus_V);
    scheduler_.set_vx_prior_at(config_.calibration.vx_V, config_.calibration.vx_std_V,
                               at_bus ? config_.calibration.vx_bus_V - config_.vx_reference_bus_V : 0.0,
                               config_.injection.vx_bus_slope_std);
  }
  publish_learned();
}

void DriveController::use_band(double band_A) {
  // The compensation and the estimator's pattern read it from the configuration; the Lq
  // learner keeps its own copy (InjectionScheduler::set_bridge_band).
  config_.dead_time.current_band_A = band_A;
  scheduler_.set_bridge_band(band_A);
}

void DriveController::publish_learned() {
  learned_version_published_ = scheduler_.learned_version();
  telemetry_.angle_correction_rad = angle_.offset_correction_rad();
  telemetry_.dead_time_band_A = config_.dead_time.current_band_A;
  telemetry_.vx_V = scheduler_.vx_V();
  telemetry_.vx_std_V = scheduler_.vx_std_V();
  telemetry_.vx_bus_slope = scheduler_.vx_bus_slope();
  telemetry_.vx_bus_slope_std = scheduler_.vx_bus_slope_std();
  telemetry_.lq_H = scheduler_.lq_H();
  telemetry_.lq_std_H = scheduler_.lq_std_H();
  telemetry_.lq_saturation_H = scheduler_.lq_saturation_H();
  telemetry_.lq_bend_H = scheduler_.lq_bend_H();
  telemetry_.lq_listening_pairs = scheduler_.lq_listening_pairs();
  telemetry_.lq_listening_learned = scheduler_.lq_listening_learned();
  telemetry_.lq_emf_d_Wb = scheduler_.lq_emf_d_Wb();
  telemetry_.lq_emf_d_std_Wb = scheduler_.lq_emf_d_std_Wb();
  telemetry_.calibrated = observer_.calibration().calibrated;
}

void DriveController::fail_calibration(CalibrationFailure why) {
  calibrating_ = false;
  calibration_failed_now_ = true;
  record_calibration_failure(why);
  restore_band();
  restore_angle();
  restore_vx();
  scheduler_.set_config(config_.injection);
}

void DriveController::record_calibration_failure(CalibrationFailure why) {
  calibration_failed_ = true;
  calibration_failure_ = why;
  switch (why) {
    case CalibrationFailure::kUncertain:
    case CalibrationFailure::kAngleOffset:
    case CalibrationFailure::kWindingWarm:
    case CalibrationFailure::kTemperatureImplausible:
    case CalibrationFailure::kAmbientHeld:
    case CalibrationFailure::kCableTakesAll:
    case CalibrationFailure::kRsOutsideWindow:
    case CalibrationFailure::kOvertemperatureLatched: calibration_outcome_ = CalibrationOutcome::kRefused; break;
    case CalibrationFailure::kTimeout: calibration_outcome_ = CalibrationOutcome::kTimedOut; break;
    case CalibrationFailure::kNone: calibration_outcome_ = CalibrationOutcome::kNone; break;
  }
  publish_calibration_state();
}

namespace {

// "N name, M name" for the non-zero counts, most frequent first (ties in index order), with
// `note` after the entry of `noted`.
template <typename Enum, std::size_t N>
std::string counts_text(const std::array<std::uint32_t, N>& counts, Enum noted = Enum{}, const std::string& note = {}) {
  std::array<std::size_t, N> order{};
  for (std::size_t k = 0; k < N; ++k) {
    order[k] = k;
  }
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return counts[a] > counts[b]; });
  std::string text;
  for (const std::size_t k : order) {
    if (counts[k] > 0U) {
      const auto e = static_cast<Enum>(k);
      text += (text.empty() ? "" : ", ") + std::to_string(counts[k]) + " " + std::string(to_string(e)) +
              (e == noted && !note.empty() ? " (" + note + ")" : std::string{});
    }
  }
  return text;
}

}  // namespace

std::string pair_outcomes_text(const OutcomeCounts& counts, const AbortCounts& aborts) {
  AbortCounts causes = aborts;
  causes[static_cast<std::size_t>(AbortCause::kNone)] = 0U;  // the pairs not aborted
  const std::string text = counts_text(counts, PairOutcome::kAborted, counts_text<AbortCause>(causes));
  return text.empty() ? "no pair" : text;
}

const char* calibration_failure_name(CalibrationFailure f) {
  switch (f) {
    case CalibrationFailure::kNone: return "none";
    case CalibrationFailure::kTimeout: return "timeout";
    case CalibrationFailure::kUncertain: return "uncertain";
    case CalibrationFailure::kAngleOffset: return "angle_offset";
    case CalibrationFailure::kWindingWarm: return "winding_warm";
    case CalibrationFailure::kTemperatureImplausible: return "temperature_implausible";
    case CalibrationFailure::kAmbientHeld: return "ambient_held";
    case CalibrationFailure::kCableTakesAll: return "cable_takes_all";
    case CalibrationFailure::kRsOutsideWindow: return "rs_outside_window";
    case CalibrationFailure::kOvertemperatureLatched: return "overtemperature_latched";
  }
  return "unknown";
}

const char* magnet_refusal_text(MagnetRefusal r) {
  switch (r) {
    case MagnetRefusal::kNone: return "none";
    case MagnetRefusal::kNotANumber: return "not a number";
    case MagnetRefusal::kImplausible: return "outside what a magnet can be";
    case MagnetRefusal::kInconsistent: return "too far from the estimate";
  }
  return "unknown";
}

void DriveController::age_magnet(double controller_s) {
  // A magnet estimate ages in thermal time; past its limit it is no estimate (and the next
  // measurement starts the smoothing afresh instead of blending with the stale value). Aged
  // with each thermal update (count_thermal_periods), not each period: magnet_age_now_s() adds
  // the time since, so the age is exact whenever it is asked for, and the limit is checked at
  // the update's rate.
  magnet_age_s_ += controller_s * observer_.time_scale();
  if (magnet_valid_ && magnet_age_s_ > config_.magnet_max_age_s) {
    magnet_valid_ = false;
    telemetry_.magnet_valid = false;  // (set with the estimate, update_magnet)
  }
}

double DriveController::magnet_var_now_C2() const {
  // Between measurements the magnets may warm or cool: the variance grows as a random walk's,
  // from what the last measurement left, with the thermal time since (no work per period).
  return magnet_var_C2_ +
         config_.magnet_drift_C_per_sqrt_s * config_.magnet_drift_C_per_sqrt_s * std::max(magnet_age_now_s(), 0.0);
}

void DriveController::publish_magnet_std() {
  telemetry_.magnet_std_C =
      std::sqrt(magnet_var_now_C2() + magnet_sys_std_C_ * magnet_sys_std_C_ + magnet_ke0_var_C2());
}

double DriveController::magnet_ke0_var_C2() const {
  // Ke0's error is a bias every magnet estimate shares (Eq. 3 referred to T0): it adds to the
  // published error bar but is not averaged away by more measurements.
  const Calibration& cal = observer_.calibration();
  if (!(cal.ke0_V_s_per_rad > 0.0)) {
    return 0.0;
  }
  const double ke0_std =
      cal.ke0_std_V_s_per_rad > 0.0 ? cal.ke0_std_V_s_per_rad : kUnknownKe0StdFraction * cal.ke0_V_s_per_rad;
  const double c = ke0_std / (cal.ke0_V_s_per_rad * config_.magnet_coefficient_per_C);
  return c * c;
}

void DriveController::pool_ke_scatter(const EventEstimate& e, double ke_ref) {
  // Relative to the calibrated Ke0 (during the calibration, to the event's own Ke), and only
  // a reading that is a plausible number: one wild event must not widen every later bar.
  const double rel = e.ke_pair_variance / (ke_ref * ke_ref);
  if (e.ke_pairs > 1 && ke_ref > 0.0 && std::isfinite(rel)) {
    const double dof = e.ke_pairs - 1;
    ke_pooled_rel_var_sum_ += dof * rel;
    ke_pooled_dof_ += dof;
  }
}

double DriveController::ke_pair_rel_var() const {
  // One pair's relative Ke variance, pooled over every event so far that had two pairs or more
  // (an event of two or three pairs says little about its own scatter); before any, a prior.
  if (ke_pooled_dof_ > 0.0) {
    return ke_pooled_rel_var_sum_ / ke_pooled_dof_;
  }
  return kUnknownKePairStdFraction * kUnknownKePairStdFraction;
}

void DriveController::set_current_noise_A(double sigma_A) {
  // The sampled line's effective noise (mean_soft_sign_of_measured): 2/3 of a sample's variance.
  pattern_noise_A_ = std::isfinite(sigma_A) && sigma_A > 0.0 ? std::sqrt(2.0 / 3.0) * sigma_A : 0.0;
}

void DriveController::restore_band() {
  // A calibration that does not complete keeps the calibration in use, and so the band its
  // Rs0 was learned with (a stored calibration's, measured or configured). Only the nameplate
  // default, which no calibration run learned, takes a band this calibration's sweep measured:
  // a measurement of the bridge in place of the configured guess. Measured at the voltage
  // limit, field-weakening pairs read 6 % low with the default 1 A against the bridge's
  // 0.74 A, and 2 % low with the measured band (docs/accuracy.md).
  const bool nameplate = !observer_.calibration().calibrated;
  if (!(nameplate && band_measured_ && !band_measured_before_)) {
    use_band(band_before_calibration_A_);
    band_measured_ = band_measured_before_;
    publish_learned();
  }
}

AngleCheckMotor DriveController::angle_check_motor() const {
  AngleCheckMotor m;
  m.flux_linkage_Wb = config_.current.flux_linkage_Wb;
  // The reluctance term only for a machine configured as salient (a torque budget, the
  // project's declaration of an interior-magnet machine: docs/configuration.md). On a
  // surface-magnet machine the commissioned Ld and Lq differ only by their errors, and that
  // difference times the no-load current would read as an offset: 0.12 degree to first order on
  // the reference (Ld +10 %, Lq -10 %: 1.1 mH times 0.6 A against the friction, over psi).
  m.ld_minus_lq_H = config_.injection.max_torque_disturbance_Nm > 0.0 ? config_.current.ld_H - config_.current.lq_H : 0.0;
  m.pole_pairs = config_.motor.pole_pairs;
  m.inertia_kg_m2 = config_.speed.inertia_kg_m2;
  // Ld and Lq each known to the fraction the Lq learning starts from (their difference's error
  // is the same whether or not the reluctance term is used).
  m.saliency_std_H = config_.injection.lq_initial_std_fraction * std::hypot(config_.current.ld_H, config_.current.lq_H);
  return m;
}

void DriveController::set_angle_correction(double correction_rad) {
  // The angles jump by the change from the next sample on. The period history moves with them
  // at the start of the next step (so that its advance is the rotor's, not the correction's),
  // not now: inside a step the history is still this period's (its sample and its mid angle).
  const double change = correction_rad - angle_.offset_correction_rad();
  angle_.set_offset_correction_rad(correction_rad);
  pending_angle_jump_rad_ += change;
  publish_learned();
}

void DriveController::restore_angle() {
  // As restore_band(): a calibration that does not complete keeps the calibration in use and
  // its angle; only the nameplate, which no check corrected, keeps this run's measurement.
  const bool nameplate = !observer_.calibration().calibrated;
  if (!(nameplate && angle_measured_ && !angle_measured_before_)) {
    set_angle_correction(angle_before_calibration_rad_);
    angle_measured_ = angle_measured_before_;
  }
}

bool DriveController::field_weakened() const {
  return field_weakening_.enabled() && field_weakening_.id_A() < 0.0;
}

void DriveController::start_calibration_sweep(double now_s) {
  sweep_restart_.reset();
  if (config_.inverter_sweep.enabled) {
    sweep_.start(config_.inverter_sweep, config_.period_s);
    sweep_restart_.attempts = 1;
  }
  // The calibration's events (and its timeout) start when the sweep has ended, or now.
  calibration_started_s_ = now_s;
}

void DriveController::finish_angle_check() {
  const AngleCheckResult& r = check_.result();
  report(check_done_, r);
  // Aborted by a stop or a lost sample, or voided by an operating point that moved: started
  // again once the drive has run a while, as the sweep is. Not turning at the first start is
  // not retried: a drive calibrating at standstill stays there (the configured offset holds).
  // A limited command at an unchanged operating point would be limited again (as for the sweep).
  // Not turning at a restart (after a stop) may be a drive still starting: it is tried again.
  const bool retry = r.outcome == AngleCheckOutcome::kAborted || r.outcome == AngleCheckOutcome::kSpeedChanged ||
                     r.outcome == AngleCheckOutcome::kUnsteady ||
                     (r.outcome == AngleCheckOutcome::kNotTurning && check_restart_.attempts > 1);
  check_restart_.ended(retry && calibrating_, kSweepAttempts);
  if (!calibrating_) {
    return;
  }
  // The residual the check saw, on top of the correction it ran with. Tens of degrees in all
  // are a commissioning error (an offset not set, a phase order or a pole count wrong), not a
  // trim: the drive says so rather than run on a guess.
  const double total = angle_.offset_correction_rad() + r.offset_rad;
  if (r.outcome == AngleCheckOutcome::kOutOfRange ||
      (r.outcome == AngleCheckOutcome::kMeasured && !(std::abs(total) <= config_.angle_check.max_offset_rad))) {
    fail_calibration(CalibrationFailure::kAngleOffset);
    return;
  }
  if (r.outcome == AngleCheckOutcome::kMeasured) {
    // Below the check's own error the angle in use stands (and counts as checked).
    const double error_bar = std::hypot(std::max(r.offset_std_rad, r.speed_std_rad), r.model_std_rad);
    const bool correct = std::abs(r.offset_rad) >= std::max(config_.angle_check.min_correction_rad, 3.0 * error_bar);
    if (correct) {
      set_angle_correction(total);
    }
    angle_measured_ = true;
    // What is left of the angle's error is the Lq learner's prior for it (its EMF share on the
    // d axis, InjectionConfig::lq_angle_std_rad): 0 on average, and as wide as the check's
    // error bar, the offset it left uncorrected, and the correction floor (the check's error
    // bar has one degree of freedom: a machine whose check corrected by 0.176 deg with
    // +-0.013 deg was exact before). Not centred on the offset left: pairs at one light load
    // would take it for certain, and a shredder whose check read -0.148 +- 0.071 deg with
    // an exact encoder read 6.2 C max in its first surge (docs/estimator.md section 5.6).
    const double left = correct ? 0.0 : std::abs(r.offset_rad);
    scheduler_.set_angle_prior(0.0, std::max({error_bar, left, config_.angle_check.min_correction_rad}));
  }
  // The sweep follows once the check has ended its wait at zero d current (step()).
  sweep_after_check_ = !check_restart_.pending;
}

void DriveController::finish_inverter_sweep(double now_s) {
  const InverterSweepResult& r = sweep_.result();
  report(sweep_done_, r);
  // Aborted by a stop or a lost sample, by a speed still settling, or unresolved (a speed
  // ramp's torque ending under its levels), during a calibration: started again once the drive
  // has run a while (kSweepHoldoff_s). A load that stays under every start stays unresolved:
  // the configured band holds, as after the last start of a speed that keeps changing.
  sweep_restart_.ended((r.outcome == InverterSweepOutcome::kAborted || r.outcome == InverterSweepOutcome::kSpeedChanged ||
                        r.outcome == InverterSweepOutcome::kUnresolved) &&
                           calibrating_,
                       kSweepAttempts);
  if (r.outcome == InverterSweepOutcome::kMeasured) {
    // The band replaces the configured one (compensation and the estimator's pattern alike).
    // The sweep's Vx is reported, not used as the calibration's prior: it reads up to 0.04 V
    // below the bridge's (the level means keep a 50 mV residual the model does not explain),
    // and Rs0 moves about 0.3 % per 0.02 V of prior; measured, it made the seeds read low
    // (docs/estimator.md section 4). The calibration's joint fit learns Vx itself.
    use_band(r.band_A);
    band_measured_ = true;
    publish_learned();
  }
  // The calibration's events (and its timeout) start now, whatever the sweep found: without a
  // measurement the configured band and Vx prior hold, as before the sweep existed.
  calibration_started_s_ = now_s;
}

void DriveController::refuse_calibration_while_overtemperature() {
  if (!calibrating_) {
    calibration_refused_on_request_ = true;
    record_calibration_failure(CalibrationFailure::kOvertemperatureLatched);
  }
}

void DriveController::start_calibration(double known_temp_C, bool from_ambient_sensor, bool ambient_held) {
  const bool was_calibrating = calibrating_;
  // The ambient sensor stopped reporting and its last reading stands for it (a loose connector,
  // the stage's own sensor check): a model's boundary may run on it a while, but Rs0 referred
  // to a reading of unknown age would carry its error into every later estimate, and be stored.
  // A calibration already running keeps the reference it started with (a fresh reading then);
  // a repeated request does not restart it on the held one.
  if (from_ambient_sensor && ambient_held) {
    if (!was_calibrating) {
      calibration_refused_on_request_ = true;
      record_calibration_failure(CalibrationFailure::kAmbientHeld);
    }
    return;
  }
  // A winding the filter holds well above the ambient sensor's reading (the drive's own losses
  // since it started, a stored warm state cooled through the downtime) is not at that
  // temperature: Rs0 referred to it would put every later estimate low by the difference (a
  // newcomer's hub motor, calibrated after a 12 s ride at 20x thermal time with the winding
  // 12 K warm, read 13.6 C low for the whole run). Refused, as an uncertain Rs0 is; the
  // calibration in use and the filter stay. Before the filter's first update it knows nothing.
  // On the nameplate's Rs0 the calibration refers T0 to the ambient plus the model's rise (below).
  // Where that rise is the drive's own losses' since a soaked start (not a restored state's, which
  // was measured through the same nameplate) and the nameplate is not taken as exact, the filter
  // is held to it: it refuses a winding warmer than those losses made it (a warm motor powered up
  // without a stored state), and its measurements, through the nameplate's error, are not the
  // reference. A newcomer's flywheel, asked after a spin-up, had the filter at 5.4 K and the model
  // at 3.9 K: refused, it ran 9.5 C RMS high on a nameplate 3 % off; referred to the model's rise
  // it reads 0.7 C (docs/estimator.md section 6, "A warm first calibration").
  const bool on_nameplate = !observer_.calibration().calibrated;
  const double model_rise = std::isfinite(observer_.model_rise_C()) ? std::max(observer_.model_rise_C(), 0.0) : 0.0;
  const bool model_is_reference =
      on_nameplate && !thermal_restored_ && observer_.calibration().rs0_std_fraction > 0.0;
  // Where the model is the reference, the filter's rise beyond it is judged below with the
  // nameplate's own uncertainty: it is as much the nameplate's error as the winding's warmth. (It
  // joins T0's uncertainty with the check off too: the band is the check's business no more than
  // the sensor's tolerance is.) A run taken with it restarted the filter at the cold end: what it
  // was taken with still holds, for a repeated request while it runs and after it failed.
  double beyond_model_C = model_is_reference ? nameplate_excess_C_ : 0.0;
  if (from_ambient_sensor && !was_calibrating && !thermal_guess_pending_) {
    // Against the ambient the filter runs on, not the one given now: a configured ambient
    // changed just before the request (no sensor) is no warmth of the winding.
    const double rise = observer_.estimate().winding_C - thermal_ambient_C_;
    if (model_is_reference) {
      beyond_model_C = std::max(std::isfinite(rise) ? rise - model_rise : 0.0, beyond_model_C);
    } else if (config_.calibration_max_winding_rise_C > 0.0 && rise > config_.calibration_max_winding_rise_C) {
      // Nothing of a calibration run has started: nothing to restore (fail_calibration).
      calibration_refused_on_request_ = true;
      telemetry_.calibration_winding_rise_C = rise;
      record_calibration_failure(CalibrationFailure::kWindingWarm);
      return;
    }
  }
  // Before the first calibration the filter's measurements go through the nameplate's Rs0, whose
  // error (a few per cent: over ten kelvin) hides a rise of a few kelvin from the guard above: a
  // newcomer's fan, calibrated after 2.5 s of run-up at 60x thermal time with the winding 2.6 K
  // above its coolant and the filter at 22 +- 14 C, read 3.4 C low for the whole run. The model
  // alone, from the soaked start a calibration at the ambient assumes, says what the drive's own
  // losses did since: Rs0 is referred to the ambient plus that rise (docs/estimator.md section 6).
  // (A repeated request while one runs takes the same reference: the restarted observer carries
  // the rise on.) The rise is the commissioned model's, known to calibration_model_rise_std_fraction
  // of itself: T0's uncertainty, kept with the calibration and in the band.
  //   The filter's rise beyond the model's, read through the nameplate, is a winding warmer
  // than the drive's losses made it (a warm motor powered up without a stored state) or the
  // nameplate's error, which no measurement on it can tell apart: a data sheet's Rs0 3 % low
  // reads a cold winding 8 K warm. A newcomer's pump, its first event before the request, was
  // refused on 7.6 K and ran on that nameplate 7.9 C RMS high. T0 stays at the cold end, the
  // ambient plus the model's rise, and half that excess joins its uncertainty: the warm end lies
  // two of it away, in the band and under the derating's T + k sigma.
  //   Beyond the limit, by the model's rise or by the filter's, the calibration is refused,
  // unless the model is the reference (above) and T0's whole uncertainty is below half the
  // nameplate's (5 % of Rs0, about 13 K): then it is still the better of the two.
  double t0_rise_std_C = 0.0;
  if (from_ambient_sensor && !thermal_guess_pending_ && on_nameplate) {
    const double rise_std_C = std::hypot(config_.calibration_model_rise_std_fraction * model_rise, 0.5 * beyond_model_C);
    const double nameplate_std_C = observer_.rs0_std_C_at(known_temp_C + model_rise);
    const bool better_than_nameplate = model_is_reference && rise_std_C < 0.5 * nameplate_std_C;
    const double limit_C = config_.calibration_max_winding_rise_C;
    if (!was_calibrating && limit_C > 0.0 && (model_rise > limit_C || beyond_model_C > limit_C) &&
        !better_than_nameplate) {
      calibration_refused_on_request_ = true;
      telemetry_.calibration_winding_rise_C = model_rise + beyond_model_C;
      record_calibration_failure(CalibrationFailure::kWindingWarm);
      return;
    }
    known_temp_C += model_rise;  // finite (above), and so its share (the fraction is a checked key)
    t0_rise_std_C = rise_std_C;
    nameplate_excess_C_ = beyond_model_C;
  }
  // An operator's reading is not second-guessed against the model alone, which may start from
  // a guess (a warm motor powered up without a stored state); but where the drive measured the
  // winding moments ago, a reading far outside that measurement's band is a mistake (a wrong
  // unit, a thermometer on the wrong part, a corrupted request): referred to it, Rs0 would put
  // every later estimate off by the difference, and it would be stored (a hostile-bus probe's
  // 150 C, with the filter at 33.5 C measured and the ambient at 25 C, was accepted and stored;
  // the drive then published 149 C and derated). Refused; the calibration in use stays.
  if (!from_ambient_sensor && !was_calibrating && !thermal_guess_pending_) {
    const ThermalEstimate e = observer_.estimate();
    const double rise = e.winding_C - known_temp_C;
    if (e.time_since_measurement_s <= kRecentMeasurement_s && telemetry_.estimates_published > 0U &&
        !(std::abs(rise) <= 4.0 * e.winding_std_C + std::max(config_.calibration_max_winding_rise_C, 0.0))) {
      calibration_refused_on_request_ = true;
      telemetry_.calibration_winding_rise_C = rise;
      record_calibration_failure(CalibrationFailure::kTemperatureImplausible);
      return;
    }
  }
  scheduler_.set_config(config_.calibration_injection);
  telemetry_.calibration_outcomes = {};
  telemetry_.calibration_aborts = {};
  // The winding is at the known temperature now; the thermal model carries it through the
  // calibration, whose own injections warm the winding a little.
  // The time scale set by set_thermal_time_scale() holds whatever the order of the calls.
  const double time_scale = observer_.time_scale();
  // What the filter has learned of the loss model is the machine's, not the moment's: it
  // survives the restart of the temperatures (and a calibration that then fails).
  drop_held_estimates();  // measurements of the winding before the restart
  const ThermalObserver before = observer_;
  observer_ = ThermalObserver(config_.thermal, observer_.calibration(), known_temp_C);
  observer_.keep_loss_errors(before);
  observer_.keep_model_rise(before);  // the drive's own warmth, still
  observer_.set_time_scale(time_scale);
  thermal_guess_pending_ = false;
  calibrating_ = true;
  calibration_failed_ = false;
  calibration_failure_ = CalibrationFailure::kNone;
  calibration_outcome_ = CalibrationOutcome::kNone;
  telemetry_.calibration_rs0_ohm = 0.0;
  telemetry_.calibration_rs0_std_ohm = 0.0;
  telemetry_.calibration_events = 0;
  calibration_started_s_ = static_cast<double>(period_) * config_.period_s;
  calibration_temp_C_ = known_temp_C;
  calibration_t0_rise_std_C_ = t0_rise_std_C;
  calibration_from_ambient_sensor_ = from_ambient_sensor;
  calibration_count_ = 0;
  calibration_rs_sum_ = 0.0;
  calibration_weight_sum_ = 0.0;
  calibration_ke_sum_ = 0.0;
  calibration_ke_sq_sum_ = 0.0;
  calibration_ke_count_ = 0;
  calibration_ke_pairs_ = 0;
  calibration_ke_model_var_sum_ = 0.0;
  magnet_reference_ = {};  // a calibration under way measures its own Ke0, at its own T0
  magnet_reference_armed_ = false;
  telemetry_.magnet_reference_at_C = 0.0;
  telemetry_.magnet_reference_std_C = 0.0;
  telemetry_.magnet_reference_events = 0;
  calibration_vx_learned_ = false;
  calibration_outside_count_ = 0;
  calibration_outside_side_ = 0;
  calibration_outside_sum_ohm_ = 0.0;
  calibration_outside_sq_sum_ohm2_ = 0.0;
  // A calibration asked for while one runs starts afresh, but what held before the first one is
  // what a failure puts back (not what the one in progress measured); its steps end here.
  if (sweep_.active()) {
    sweep_.abort();
  }
  if (check_.active()) {
    check_.abort();
  }
  sweep_after_check_ = false;
  if (!was_calibrating) {
    band_before_calibration_A_ = config_.dead_time.current_band_A;
    band_measured_before_ = band_measured_;
    angle_before_calibration_rad_ = angle_.offset_correction_rad();
    angle_measured_before_ = angle_measured_;
    vx_before_calibration_ = scheduler_.vx_state();
  }
  // The calibration learns the bridge's voltage afresh, from the configured guess: conditioned
  // on a stored or learned Vx it could not see a changed bridge (another inverter, PWM
  // frequency or dead time), and one that cannot learn Vx (at speed, under load) would pass
  // its Rs0 uncertainty check on the old Vx's error bar.
  scheduler_.set_vx_prior(config_.injection.vx_initial_V, config_.injection.vx_initial_std_V);
  scheduler_.reset_vx_bus_slope(config_.injection.vx_bus_slope_std);
  // First the rotor angle (the sweep and the events inject d current, which an angle off the
  // rotor's turns into torque), then the bridge, then the events.
  check_restart_.reset();
  if (config_.angle_check.enabled) {
    check_.start(config_.angle_check, angle_check_motor(), config_.period_s);
    check_restart_.attempts = 1;
    sweep_restart_.reset();
  } else {
    start_calibration_sweep(calibration_started_s_);
  }
  publish_calibration_state();
}

void DriveController::publish_calibration_state() {
  // Called wherever the calibration's state changes (not every period), and at once: a
  // calibration may end (abort) while the drive is in its safe state, where step() returns
  // early.
  telemetry_.calibrating = calibrating_;
  telemetry_.calibration_failed = calibration_failed_;
  telemetry_.calibration_failure = calibration_failure_;
  telemetry_.calibration_outcome = calibration_outcome_;
}

void DriveController::abort_calibration() {
  if (calibrating_) {
    calibrating_ = false;
    calibration_outcome_ = CalibrationOutcome::kAborted;
    publish_calibration_state();
    if (sweep_.active()) {
      sweep_.abort();
      report(sweep_done_, sweep_.result());
    }
    if (check_.active()) {
      const bool measuring = !check_.decided();
      check_.abort();
      if (measuring) {
        report(check_done_, check_.result());
      }
    }
    sweep_after_check_ = false;
    sweep_restart_.reset();
    check_restart_.reset();
    restore_band();
    restore_angle();
    restore_vx();
    scheduler_.set_config(config_.injection);
  }
}

void DriveController::restore_vx() {
  // A calibration that does not complete keeps the calibration in use, and the Vx its Rs0 was
  // learned with (or the one learned since).
  scheduler_.set_vx_state(vx_before_calibration_);
}

bool DriveController::configure_injection(InjectionMethod method, Separation separation, double f_A, double interval_s) {
  // Events only on request: an interval no run reaches.
  constexpr double kOnRequestOnly_s = 1e12;
  InjectionConfig c = config_.injection;
  c.method = method;
  c.separation = separation;
  if (f_A > 0.0 && std::isfinite(f_A)) {
    c.f_A = f_A;
  }
  c.interval_s = interval_s > 0.0 && std::isfinite(interval_s) ? interval_s : kOnRequestOnly_s;
  if (c.method == config_.injection.method && c.separation == config_.injection.separation && c.f_A == config_.injection.f_A &&
      c.interval_s == config_.injection.interval_s) {
    return false;
  }
  config_.injection = c;
  if (!calibrating_) {
    scheduler_.set_config(c);
  }
  return true;
}

// The loop's last command was a motoring one (it ran, and no pulse was on): low-passed, it is
// the machine's motoring voltage, which the voltage budget of a pair starting in this period
// takes instead of the model's (InjectionScheduler::set_motoring_voltage). Its mean and its
// spread, not its peaks: the current loop's proportional answer to the sensors' noise reaches
// several volts in single periods (the reference's peaks over 0.2 s, taken as the motoring
// voltage, left its pairs at rated speed a third of their signal and read 4 % low). Out of
// line, as weaken_field: not in the injecting periods' instructions.
[[gnu::noinline]] void DriveController::track_motoring_voltage(double now_s, double omega_e_rad_s) {
  const Dq& v = current_.status().v_unlimited_V;
  Dq& m = motoring_voltage_mean_V_;
  const double v_sq = v.d * v.d + v.q * v.q;
  // A plain average over its first periods, then the low-pass: the first sample after a start
  // or a sweep (the loop's transient, the sweep's last level) weighs no more than any other.
  double gain = motoring_voltage_gain_;
  if (motoring_voltage_periods_ < motoring_voltage_settle_periods_) {
    gain = std::max(gain, 1.0 / static_cast<double>(++motoring_voltage_periods_));
  }
  if (gain >= 1.0) {
    // The first sample is taken, not blended: a mean left not a number before (a period with no
    // command to read) must not stay so.
    m = {};
    motoring_voltage_mean_sq_V2_ = 0.0;
    motoring_omega_mean_rad_s_ = 0.0;
    motoring_current_mean_A_ = {};
  }
  m.d += gain * (v.d - m.d);
  m.q += gain * (v.q - m.q);
  motoring_voltage_mean_sq_V2_ += gain * (v_sq - motoring_voltage_mean_sq_V2_);
  // The speed and the motoring current that mean belongs to, filtered alike (a ramp's mean
  // voltage lags its speed, and field weakening's d current, by the filter's 20 ms:
  // weaken_field's watch takes the change from these).
  motoring_omega_mean_rad_s_ += gain * (omega_e_rad_s - motoring_omega_mean_rad_s_);
  const Dq motoring_A = last_motoring_current_A();
  motoring_current_mean_A_.d += gain * (motoring_A.d - motoring_current_mean_A_.d);
  motoring_current_mean_A_.q += gain * (motoring_A.q - motoring_current_mean_A_.q);
  // Known once the filter has seen three of its time constants.
  if (motoring_voltage_periods_ >= motoring_voltage_settle_periods_) {
    scheduler_.set_motoring_voltage(now_s, m, motoring_voltage_mean_sq_V2_);
  }
}

// Kept out of line, as the drive runs it only with field weakening on (the step without it
// pays one test).
[[gnu::noinline]] bool DriveController::weaken_field(bool levels_active, double omega_e_rad_s,
                                                     bool& release_motoring) {
  const double limit_V = current_.status().voltage_limit_V;
  if (scheduler_.phase() == SchedulerPhase::kIdle) {
    // Held while the sweep's or the angle check's levels run (their separations take the
    // motoring point as still; neither runs in field weakening: step() refuses them), not
    // while they wait to start again.
    if (!levels_active) {
      const Dq& v = current_.status().v_unlimited_V;
      field_weakening_.step(std::sqrt(v.d * v.d + v.q * v.q), limit_V, omega_e_rad_s, injection_current_limit_A_);
    }
    pair_watch_.armed = false;
  } else {
    // A pair holds the regulator, so that its recordings share one motoring point. The EMF
    // moves with the speed all the same: a salient servo accelerating at 1000 rad/s^2 through
    // 1.4 times its id = 0 speed, its pair's -F pulse doing the weakening the held id no longer
    // did, lost its current loop when the pulse ramped off (the EMF above the bus; a hardware
    // over-current trip, docs/estimator.md section 2). So the motoring point's voltage is
    // followed through the pair: as the loop commanded it before the pair (its tracked mean,
    // with the speed and current filtered alike), plus the change Eq. 3 gives for the speed
    // and the current since (vd = Rs id - w Lq iq, vq = w (psi + Ld id) + Rs iq, at the held
    // id: the model's errors enter only through the change). Where it would take more than
    // half the reserve the regulator keeps, the pair ends (and the regulator takes its pulse
    // over: hand_pulse_over).
    if (!pair_watch_.armed) {
      pair_watch_.armed = motoring_voltage_periods_ >= motoring_voltage_settle_periods_;
      pair_watch_.v_V = motoring_voltage_mean_V_;
      pair_watch_.omega_e_rad_s = motoring_omega_mean_rad_s_;
      pair_watch_.i_A = motoring_current_mean_A_;
    }
    if (pair_watch_.armed) {
      // Eq. 3's steady state at the held d current, less the same at the mean's point.
      const Watch& w0 = pair_watch_;
      const double lq = scheduler_.lq_H();
      const double ld = config_.current.ld_H;
      const double rs = config_.current.rs_ohm;
      const double psi = config_.current.flux_linkage_Wb;
      const double id = field_weakening_.id_A();
      const Dq motoring_A = last_motoring_current_A();
      const double vd = w0.v_V.d + rs * (id - w0.i_A.d) - lq * (omega_e_rad_s * motoring_A.q - w0.omega_e_rad_s * w0.i_A.q);
      const double vq = w0.v_V.q + omega_e_rad_s * (psi + ld * id) - w0.omega_e_rad_s * (psi + ld * w0.i_A.d) +
                        rs * (motoring_A.q - w0.i_A.q);
      const double fraction = 0.5 * (1.0 + field_weakening_.voltage_fraction());
      if (vd * vd + vq * vq > fraction * fraction * limit_V * limit_V) {
        release_motoring = true;
        pair_watch_.armed = false;
      }
    }
  }
  // In field weakening no pair starts before the watch can arm (the motoring voltage tracked for
  // three of its filter's time constants since the drive was enabled or a sweep ended).
  return !field_weakening_.settled() || (field_weakened() && motoring_voltage_periods_ < motoring_voltage_settle_periods_);
}

[[gnu::noinline]] void DriveController::hand_pulse_over(Dq& motoring_A) {
  // A pair that ends early (the watch above, the current limit, a calibration's commissioning
  // step, a lost sample) takes its pulse away at once. In field weakening a -F pulse was doing
  // part of the weakening: the regulator takes its d current over, this period's reference
  // included, so that the d current does not step back, and relaxes it from there; the q
  // current keeps within the drive's limit beside it. Within the regulator's own bound
  // (control.field_weakening_max_current_A, psi/Ld by default: beyond it the stator's flux
  // would reverse the magnet's): the part of a pulse beyond it does step back.
  const double pulse_d_A = std::min(telemetry_.injection_A.d, 0.0);  // last period's pulse
  const double before_A = field_weakening_.id_A();
  field_weakening_.take_over(before_A + pulse_d_A, injection_current_limit_A_);
  const double moved_A = field_weakening_.id_A() - before_A;
  if (moved_A < 0.0) {
    motoring_A.d += moved_A;
    const double limit_A = derating_.current_limit_A;
    const double q_room_A = std::sqrt(std::max(limit_A * limit_A - motoring_A.d * motoring_A.d, 0.0));
    motoring_A.q = std::clamp(motoring_A.q, -q_room_A, q_room_A);
  }
}

Dq DriveController::motoring_reference(const DriveCommand& command) {
  // Field weakening's d current takes its share of the current limit first; the torque gets
  // what is left of the circle, and on a salient machine its reluctance part, 3/2 p (Ld - Lq)
  // id iq (Eq. 10), changes the torque each ampere of iq gives (with the learned Lq): a torque
  // command taken as Kt iq alone gave an IPM traction motor in field weakening 51-83 % more
  // torque than asked (a newcomer's probe, docs/daemon.md). The flux is kept above half the
  // magnets', as the torque-neutral pulses keep it.
  const double id_A = field_weakening_.id_A();
  double limit = derating_.current_limit_A;
  double kt_Nm_per_A = kt_dq_Nm_per_A_;
  if (id_A != 0.0) {
    limit = std::sqrt(std::max(limit * limit - id_A * id_A, 0.0));
    // Eq. 10 with the reluctance term, per ampere of iq.
    kt_Nm_per_A = std::max(electromagnetic_torque_Nm(config_.current.flux_linkage_Wb, config_.current.ld_H,
                                                     scheduler_.lq_H(), config_.motor.pole_pairs, {id_A, 1.0}),
                           0.5 * kt_dq_Nm_per_A_);
  }
  bool speed_limited = false;
  double torque = 0.0;
  if (command.mode == DriveMode::kSpeed) {
    double reference = command.speed_ref_rad_s;
    if (std::abs(reference) > speed_limit_rad_s_) {  // (infinite without a limit)
      reference = std::copysign(speed_limit_rad_s_, reference);
      speed_limited = true;
    }
    if (++speed_divider_ >= config_.speed_decimation) {
      speed_divider_ = 0;
      const double speed = angle_.mechanical_speed_rad_s();
      const double dt = config_.speed.period_s;
      double feed_forward = 0.0;
      if (!speed_loop_started_) {
        // Speed mode begins (on enabling, or from torque mode), bumplessly: the loop takes
        // over the torque the drive asks now (zero on enabling; torque mode's, held in
        // torque_demand_Nm_ until this update) as its integral, and the ramp starts from
        // where the shaft is, not from rest. An integral left at what speed mode last held
        // jolted the shaft on the switch (DriveNode.ASwitchToSpeedModeDoesNotJoltTheShaft).
        speed_loop_started_ = true;
        const double torque_limit_Nm = std::min(limit * kt_Nm_per_A, config_.speed.max_torque_Nm);
        speed_.reset(std::clamp(torque_demand_Nm_, -torque_limit_Nm, torque_limit_Nm));
        speed_ramp_ref_rad_s_ = speed;
      }
      if (config_.speed_ramp_rad_s2 > 0.0) {
        if (!std::isfinite(speed_ramp_ref_rad_s_)) {
          speed_ramp_ref_rad_s_ = speed;
        }
        const double max_step = config_.speed_ramp_rad_s2 * dt;
        const double step = std::clamp(reference - speed_ramp_ref_rad_s_, -max_step, max_step);
        speed_ramp_ref_rad_s_ += step;
        reference = speed_ramp_ref_rad_s_;
        feed_forward = config_.speed.inertia_kg_m2 * step / dt;
      }
      torque_demand_Nm_ = speed_.step(reference, speed, limit * kt_Nm_per_A, voltage_limited_since_speed_step_,
                                      feed_forward);
      voltage_limited_since_speed_step_ = false;
    }
    torque = torque_demand_Nm_;
  } else if (command.mode == DriveMode::kTorque) {
    speed_loop_started_ = false;
    torque = command.torque_ref_Nm;
    // Near the limit the torque folds back as a proportional speed loop would hold the shaft
    // there: at most G (limit - speed) forwards, G (-limit - speed) backwards (infinite bounds
    // without a limit). Beyond the limit the bound changes sign: the drive brakes (regenerates)
    // the shaft back. Said to limit only where it binds tighter than the current limit does.
    const double speed = angle_.mechanical_speed_rad_s();
    const double upper = speed_limit_gain_Nm_s_ * (speed_limit_rad_s_ - speed);
    const double lower = speed_limit_gain_Nm_s_ * (-speed_limit_rad_s_ - speed);
    if (torque > upper) {
      torque = upper;
      speed_limited = upper < limit * kt_Nm_per_A;
    } else if (torque < lower) {
      torque = lower;
      speed_limited = lower > -limit * kt_Nm_per_A;
    }
    torque_demand_Nm_ = torque;  // for a switch to speed mode
  }
  // Eq. 10: Tem = Kt iqr (id = 0 control below the field-weakening speed; above it, Kt with the
  // reluctance term of field weakening's d current).
  const double wanted = torque / kt_Nm_per_A;
  telemetry_.motoring_iq_wanted_A = wanted;  // DriveTelemetry::current_limited() compares
  telemetry_.motoring_iq_limit_A = limit;
  telemetry_.speed_limited = speed_limited;
  return {id_A, std::clamp(wanted, -limit, limit)};
}

void DriveController::clear_motoring_telemetry() {
  telemetry_.motoring_iq_wanted_A = 0.0;
  telemetry_.motoring_iq_limit_A = std::numeric_limits<double>::infinity();
  telemetry_.speed_limited = false;
}

void DriveController::handle_pair(const PairResult& r) {
  ++telemetry_.outcomes[static_cast<std::size_t>(r.outcome)];
  if (calibrating_) {
    ++telemetry_.calibration_outcomes[static_cast<std::size_t>(r.outcome)];
    ++telemetry_.calibration_aborts[static_cast<std::size_t>(r.abort_cause)];  // (kNone: not aborted)
  }
  telemetry_.lq_saturation_resolved = scheduler_.lq_saturation_resolved();  // a pair may have resolved it
  report(last_pair_, r);
}

// The event's pairs span up to seconds: the filter takes its estimate at the event's own time,
// on the filter's clock (its last update was thermal_elapsed_s_ ago). A time after the last
// update (within the period since it; one after publication is held: hold_estimate) takes the
// present estimate.
double DriveController::measurement_age_s(const EventEstimate& e) const {
  return e.measured_at_s > 0.0 ? std::max(e.time_s - e.measured_at_s - thermal_elapsed_s_, 0.0) : 0.0;
}

void DriveController::count_calibration_outside_window(const EventEstimate& e) {
  // A calibration's events fit Rs and the bridge's voltage together on a motor at rest or
  // unloaded, and agree to a fraction of a per cent (a newcomer's escalator: 357.4-359.4 mOhm
  // over nine events). Several in a row on one side of the window the nameplate sets are the
  // winding's resistance, and the nameplate is not this winding's: its datasheet's line-to-line
  // 0.687 ohm entered as the phase's put the window at 0.465-1.39 ohm, every event was refused,
  // and the calibration went on until later events, on the unlearned bridge voltage, ended it as
  // uncertain, a reason that named neither the nameplate nor the window (docs/accuracy.md, round
  // 11). Refused early, with the resistance measured (docs/estimator.md section 6). Not adopted:
  // a window is there to keep a wrong measurement out, and which of the two is wrong is the
  // commissioning engineer's to say. (The event's Rs is its joint fit's, finite when it reaches
  // here: plausible() refuses NaN as well, so a non-finite one is not counted.)
  if (!std::isfinite(e.rs_ohm)) {
    return;
  }
  const InjectionConfig& window = config_.calibration_injection;
  const int side = e.rs_ohm < window.rs_min_ohm ? -1 : (e.rs_ohm > window.rs_max_ohm ? 1 : 0);
  if (side == 0) {
    return;  // refused for its variance, not for where it lies
  }
  if (side != calibration_outside_side_ || calibration_outside_count_ == 0) {
    calibration_outside_side_ = side;
    calibration_outside_count_ = 0;
    calibration_outside_sum_ohm_ = 0.0;
    calibration_outside_sq_sum_ohm2_ = 0.0;
  }
  ++calibration_outside_count_;
  calibration_outside_sum_ohm_ += e.rs_ohm;
  calibration_outside_sq_sum_ohm2_ += e.rs_ohm * e.rs_ohm;
  if (calibration_outside_count_ >= kCalibrationOutsideWindowEvents) {
    const double n = static_cast<double>(calibration_outside_count_);
    const double mean = calibration_outside_sum_ohm_ / n;
    telemetry_.calibration_rs0_ohm = mean;
    telemetry_.calibration_events = calibration_outside_count_;
    telemetry_.calibration_rs0_std_ohm =
        std::sqrt(std::max(calibration_outside_sq_sum_ohm2_ - n * mean * mean, 0.0) / (n - 1.0));
    fail_calibration(CalibrationFailure::kRsOutsideWindow);
  }
}

void DriveController::handle_estimate(const EventEstimate& e) {
  report(last_event_, e);
  if (e.outcome != EventOutcome::kPublished) {
    ++telemetry_.events_without_estimate;
    if (calibrating_ && e.outcome == EventOutcome::kImplausible && config_.estimator == EstimatorKind::kInjection) {
      count_calibration_outside_window(e);
    }
    return;
  }
  if (calibrating_) {
    calibration_outside_count_ = 0;  // a measurement inside the window ends a run of those outside
    // Inverse-variance weights: an event whose inverter voltage was still unknown carries
    // a large error bar and must not pull Rs0.
    // Each event's Rs is referred back to the known temperature through Eq. 1, at the winding
    // temperature the thermal model predicts now (the calibration's own injection losses warm
    // it). The model's temperature at the event's own time (ThermalObserver::winding_at_age_C)
    // was tried: no better in the simulator over 20 seeds, and 1.3-1.8 C higher in the
    // two-process HIL while that calibrated at 400x thermal time, where the winding cools
    // between an event's pairs and its publication (docs/estimator.md section 7, docs/hil.md).
    // (An event dated after now, which the calibration's pairs at no load do not make, is
    // referred back by the model's rate of warming: the calibration cannot wait for it.)
    // The winding's share only: a motor cable (ThermalModelConfig::cable_resistance_20C_ohm) is
    // at the ambient now and is stored at T0, as the winding (ThermalObserver::winding_rs0_ohm).
    const double rs_now = referred_back_ohm(e.rs_ohm, e.measured_at_s - e.time_s);
    const double rs_at_known = resistance_referred_to_C(
        rs_now, observer_.estimate().winding_C, calibration_temp_C_, observer_.cable_resistance_now_ohm(),
        cable_resistance_at_C(config_.thermal.cable_resistance_20C_ohm, calibration_temp_C_),
        config_.thermal.conductor_inferred_zero_C);  // Eq. 1
    const double w = 1.0 / std::max(e.rs_std_ohm * e.rs_std_ohm, 1e-12);
    calibration_rs_sum_ += w * rs_at_known;
    calibration_weight_sum_ += w;
    ++calibration_count_;
    calibration_vx_learned_ = calibration_vx_learned_ || e.vx_from_event;
    if (e.has_emf) {
      calibration_ke_sum_ += e.ke_V_s_per_rad;
      calibration_ke_sq_sum_ += e.ke_V_s_per_rad * e.ke_V_s_per_rad;
      ++calibration_ke_count_;
      calibration_ke_pairs_ += e.ke_pairs;
      calibration_ke_model_var_sum_ += e.ke_shared_std_V_s_per_rad * e.ke_shared_std_V_s_per_rad +
                                       e.ke_systematic_std_V_s_per_rad * e.ke_systematic_std_V_s_per_rad;
      pool_ke_scatter(e, std::abs(e.ke_V_s_per_rad));
    }
    if (calibration_count_ >= config_.calibration_events) {
      complete_calibration();
    }
    return;
  }
  if (e.measured_at_s > e.time_s) {
    hold_estimate(e);
  } else {
    fuse_estimate(e, measurement_age_s(e));
  }

  // Magnet temperature from the EMF constant relative to its calibrated value.
  const Calibration& cal = observer_.calibration();
  if (e.has_emf && cal.ke0_V_s_per_rad > 0.0) {
    update_magnet(e, cal);
  } else if (magnet_reference_armed_) {
    offer_magnet_reference(e);  // every published event watches the window; those with EMF fill it
  }
}

void DriveController::offer_magnet_reference(const EventEstimate& e) {
  const Calibration& cal = observer_.calibration();
  // Only after a calibration run at rest in this run (complete_calibration arms it): its premise,
  // a machine soaked at T0, is the rotor's too, and the filter restarted there. A stored
  // calibration without Ke0, a restored or guessed thermal state, say nothing of the rotor.
  if (!magnet_reference_armed_ || !(config_.magnet_reference_max_std_C > 0.0) || !cal.calibrated) {
    return;
  }
  // Where the rotor is. The drive's thermal model lumps the rotor with the housing (docs/
  // estimator.md section 7): its heat comes through the air gap and the bearings, so from the
  // soak at T0 it lags whatever warms or cools it, and lies between T0, the ambient and the
  // housing's estimate (a coolant that moved since the calibration leaves the rotor behind,
  // below or above both). Uniform over that span, and the housing estimate's own uncertainty.
  // In the first minutes after the calibration the span is a few kelvin: the window this draws
  // on. (Its own iron loss can lift the rotor above the housing: a rotor that carries much of it
  // under a strong housing cooling is beyond this, docs/estimator.md section 8.)
  const ThermalEstimate th = observer_.estimate();
  const double lo = std::min({cal.t0_C, thermal_ambient_C_, th.housing_C});
  const double hi = std::max({cal.t0_C, thermal_ambient_C_, th.housing_C});
  const double reference_C = 0.5 * (lo + hi);
  const double housing_std = observer_.housing_std_C();
  const double reference_std = std::sqrt((hi - lo) * (hi - lo) / 12.0 + housing_std * housing_std);
  const double alpha = config_.magnet_coefficient_per_C;
  const double scale = 1.0 + alpha * (reference_C - cal.t0_C);
  if (!(telemetry_.thermal_valid && reference_std < config_.magnet_reference_max_std_C && scale > 0.5)) {
    // The window closed (the machine warmed, the filter lost its state): what it pooled is taken
    // when it is enough for a calibration cut short, else nothing. It does not open again: after
    // a warm spell the rotor, slowest to cool, may lie above the housing and the ambient, where
    // the span cannot reach (a screw press whose first EMF came at a flush after 90 minutes of
    // pressing and 100 of cooling read its magnets 7 K low through such a Ke0).
    if (config_.calibration_min_events > 0 && magnet_reference_.events >= config_.calibration_min_events) {
      adopt_magnet_reference();
    }
    magnet_reference_ = {};
    magnet_reference_armed_ = false;
    return;
  }
  if (!e.has_emf) {
    return;  // an event without an EMF reading (time-based pairs) only watches the window
  }
  // Eq. 3's Ke referred to T0 as update_magnet() refers it back: Ke = Ke0 (1 + alpha_m (T - T0)).
  const double ke0 = e.ke_V_s_per_rad / scale;
  const double model_var = (e.ke_shared_std_V_s_per_rad * e.ke_shared_std_V_s_per_rad +
                            e.ke_systematic_std_V_s_per_rad * e.ke_systematic_std_V_s_per_rad) /
                           (scale * scale);
  // dKe0 / dT = -Ke0 alpha_m / scale: the rotor's uncertainty in Ke0, the same for the window's
  // events (adopt_magnet_reference does not divide it by their number).
  const double reference_var = (ke0 * alpha * reference_std / scale) * (ke0 * alpha * reference_std / scale);
  // A reading no magnet of this motor gives (not a number, or further from the commissioned
  // flux than a calibration's Ke0 is warned about, kKe0OffMotor) is passed over; the window
  // stays open.
  const double commissioned = config_.motor.pole_pairs * config_.current.flux_linkage_Wb;
  if (!(std::isfinite(ke0) && ke0 > 0.0 && std::isfinite(model_var) && std::isfinite(reference_var) &&
        std::abs(ke0 / commissioned - 1.0) <= kKe0OffMotor)) {
    return;
  }
  MagnetReferencePool& p = magnet_reference_;
  ++p.events;
  p.pairs += e.ke_pairs;
  p.ke0_sum += ke0;
  p.ke0_sq_sum += ke0 * ke0;
  p.model_var_sum += model_var;
  p.reference_var_sum += reference_var;
  p.reference_C_sum += reference_C;
  p.reference_std_sum += reference_std;
  pool_ke_scatter(e, e.ke_V_s_per_rad);
  if (p.events >= config_.calibration_events) {
    adopt_magnet_reference();
  }
}

void DriveController::adopt_magnet_reference() {
  // As a calibration's Ke0 (calibration_ke0_std): the events' mean; its error the larger of
  // their scatter and the pooled pair scatter, plus what they share (the events' Rs and Vx
  // models, and the rotor's temperature, the same span for them all: not divided by N).
  const MagnetReferencePool& p = magnet_reference_;
  const double n = p.events;
  const double ke0 = p.ke0_sum / n;
  double var = 0.0;
  if (n >= 3.0) {
    var = std::max(0.0, (p.ke0_sq_sum - n * ke0 * ke0) / (n - 1.0)) / n;
  }
  if (p.pairs > 0) {
    var = std::max(var, ke0 * ke0 * ke_pair_rel_var() / p.pairs);
  }
  var += (p.model_var_sum + p.reference_var_sum) / n;
  const double std = std::sqrt(var);
  if (!(std::isfinite(ke0) && ke0 > 0.0 && std::isfinite(std))) {
    magnet_reference_ = {};
    return;
  }
  Calibration c = observer_.calibration();
  c.ke0_V_s_per_rad = ke0;
  c.ke0_std_V_s_per_rad = std;
  observer_.set_calibration(c);
  magnet_reference_armed_ = false;
  report(magnet_reference_done_, c);
  telemetry_.magnet_reference_at_C = p.reference_C_sum / n;
  telemetry_.magnet_reference_std_C = p.reference_std_sum / n;
  telemetry_.magnet_reference_events = p.events;
  magnet_reference_ = {};
  magnet_valid_ = false;  // the next EMF reading is the first against this Ke0
  telemetry_.magnet_valid = false;
  magnet_reset_ = true;
}

// The calibration's Rs0 and Ke0 from the events it has published (calibration_events of them, or
// at its timeout at least calibration_min_events): refused where they are too uncertain, leave
// the winding no resistance beside a cable, or put the winding warm; else in use from now on.
void DriveController::complete_calibration() {
  const double rs0 = calibration_rs_sum_ / calibration_weight_sum_;
  // The events' inverse-variance standard error. They share the inverter-voltage prior,
  // so this is a lower bound on Rs0's uncertainty: a calibration that fails it is
  // uncertain at least this much.
  const double rs0_std = std::sqrt(1.0 / calibration_weight_sum_);
  telemetry_.calibration_rs0_ohm = rs0;
  telemetry_.calibration_rs0_std_ohm = rs0_std;
  telemetry_.calibration_events = calibration_count_;
  if (!(rs0_std <= config_.calibration_max_rs0_std_fraction * std::abs(rs0))) {
    fail_calibration(CalibrationFailure::kUncertain);
    return;
  }
  // Rs0 holds the cable too: a cable configured longer (or a winding measured lower) than
  // the whole resistance leaves Eq. 1 no winding, and a negative one turns its slope over.
  // (The configuration refuses the same of a stored Rs0: cable_leaves_no_winding.)
  if (!(rs0 > cable_resistance_at_C(config_.thermal.cable_resistance_20C_ohm, calibration_temp_C_))) {
    fail_calibration(CalibrationFailure::kCableTakesAll);
    return;
  }
  // The Rs0 the drive holds (a calibration run's, a stored one's, or the nameplate's) reads
  // the new Rs0 through it as a temperature (Eq. 1). Where that puts the winding more than
  // calibration.max_winding_rise_C above the ambient sensor's reading this run is referred
  // to, beyond three standard errors of the two Rs0 (the new one's; the held one's
  // calibration.rs0_std_fraction, 5 % for the nameplate's: about 13 K, so only a winding
  // some 45 K warm is seen through it), the winding was warm, not at T0: referred to the
  // sensor, every later estimate would read low by the difference. A newcomer's press, powered up 10 minutes
  // after a stop with the winding at 70 C in a 25 C shop and no stored thermal state,
  // recalibrated at once: the filter had measured nothing yet, the request's guard passed,
  // Rs0 came 17.5 % above the stored one, and the drive read 34.6 C RMS low with the truth
  // never inside its band (docs/estimator.md section 6, "A warm recalibration"). Refused
  // (winding_warm); the calibration in use stays, and the filter starts again from the
  // temperature the old calibration reads, with a start's wide band and no gate for its
  // first measurement. An operator's temperature is not second-guessed here (a rewound
  // or replaced motor: calibrate at a known temperature, or remove the stored calibration).
  if (calibration_from_ambient_sensor_ && config_.calibration_max_winding_rise_C > 0.0) {
    const double reads_C = observer_.temperature_from_resistance_C(rs0);
    const double new_std_C = std::abs(observer_.temperature_from_resistance_C(rs0 + rs0_std) - reads_C);
    const double held_std_C = observer_.rs0_std_C_at(reads_C);
    const double rise = reads_C - calibration_temp_C_;
    if (std::isfinite(rise) &&
        rise > config_.calibration_max_winding_rise_C + 3.0 * std::hypot(new_std_C, held_std_C)) {
      telemetry_.calibration_winding_rise_C = rise;
      fail_calibration(CalibrationFailure::kWindingWarm);
      const ThermalObserver refused = observer_;
      start_thermal_from_guess(reads_C);
      observer_.keep_loss_errors(refused);
      return;
    }
  }
  Calibration c;
  c.rs0_ohm = rs0;
  c.t0_C = calibration_temp_C_;
  c.t0_rise_std_C = calibration_t0_rise_std_C_;
  c.ke0_V_s_per_rad = calibration_ke_count_ > 0 ? calibration_ke_sum_ / calibration_ke_count_ : 0.0;
  c.ke0_std_V_s_per_rad = calibration_ke0_std(c.ke0_V_s_per_rad);
  c.calibrated = true;
  // No EMF in its events (at rest): Ke0 from the first turning events (offer_magnet_reference).
  magnet_reference_armed_ = !(c.ke0_V_s_per_rad > 0.0);
  if (band_measured_) {
    // The band Rs0 was learned with, when a sweep measured it (this run's, or the stored
    // calibration's when this run's sweep was void).
    c.dead_time_band_A = config_.dead_time.current_band_A;
  }
  // Likewise the angle correction, when a check measured it.
  c.angle_correction_measured = angle_measured_;
  c.angle_correction_rad = angle_measured_ ? angle_.offset_correction_rad() : 0.0;
  // And the bridge's voltage Rs0 was learned with, when this run's events learned it (not
  // the configured guess they started from).
  if (config_.injection.fit_dead_time && calibration_vx_learned_) {
    // Referred to the reference bus, with its error where the events measured it: the
    // error at the reference would carry the bus slope's prior times the distance, and a
    // restart adds that again (docs/estimator.md section 4).
    const double u = vx_referred_to_bus_ ? scheduler_.last_learned_bus_offset_V() : 0.0;
    c.vx_V = scheduler_.vx_V();
    c.vx_std_V = scheduler_.vx_std_at_V(u);
    c.vx_bus_V = vx_referred_to_bus_ ? config_.vx_reference_bus_V + u : 0.0;
  }
  calibrating_ = false;
  scheduler_.set_config(config_.injection);
  // The filter keeps its state (the winding has warmed during the calibration); only the
  // temperature scale changes.
  observer_.set_calibration(c);
  publish_learned();
  report(calibration_done_, c);
  magnet_valid_ = false;  // the next estimate is against the new Ke0, not blended with the old
  telemetry_.magnet_valid = false;
  magnet_reset_ = true;
  calibration_outcome_ = CalibrationOutcome::kDone;
  publish_calibration_state();
}

void DriveController::fuse_estimate(const EventEstimate& e, double age_s) {
  ResistanceEstimate out;
  out.time_s = e.measured_at_s > 0.0 ? std::max(e.measured_at_s + age_s, e.time_s) : e.time_s;
  out.measured_at_s = e.measured_at_s > 0.0 ? std::min(e.measured_at_s, out.time_s) : out.time_s;
  out.rs_ohm = e.rs_ohm;
  out.rs_std_ohm = e.rs_std_ohm;
  out.winding_C = observer_.temperature_from_resistance_C(e.rs_ohm);
  out.vx_V = e.vx_V;
  out.vx_std_V = e.vx_std_V;
  out.lq_H = e.lq_H;
  out.pairs = e.pairs;
  out.vx_learning = e.vx_learning;
  out.bus_spread_V = e.bus_spread_V;
  out.vx_refused_bus_spread = e.vx_refused_bus_spread;
  out.joint_rs_ohm = e.joint_rs_ohm;
  out.joint_vx_V = e.joint_vx_V;
  if (thermal_guess_pending_) {
    // A measurement before the first thermal update: the filter starts from a guess here.
    start_thermal_from_guess(observer_.estimate().winding_C);
  }
  // The line the estimate extrapolates along (EventEstimate::measured_from_s), in ages.
  const double from_age_s = age_s + (e.measured_at_s - e.measured_from_s);
  const double to_age_s = age_s + (e.measured_at_s - e.measured_to_s);
  // The bus slope's share of the error bar goes to the filter as its state (BusSlopeTerm), where
  // the filter takes the term.
  const BusSlopeTerm slope{e.bus_slope_sensitivity_ohm, e.bus_slope, e.bus_slope_var};
  const double slope_var = slope.usable() ? std::max(e.rs_bus_slope_var_ohm2, 0.0) : 0.0;
  const double std_ohm = std::sqrt(std::max(e.rs_std_ohm * e.rs_std_ohm - slope_var, 0.0));
  const double systematic_ohm = std::sqrt(std::max(e.rs_systematic_std_ohm * e.rs_systematic_std_ohm - slope_var, 0.0));
  out.fused = observer_.update_resistance(e.rs_ohm, std_ohm, systematic_ohm, age_s, from_age_s, to_age_s, slope);
  if (out.fused) {
    ++telemetry_.estimates_published;
    // The published temperature follows the fused measurement at once, not at the next
    // thermal update (a start from a guess would otherwise show the guess for one more period).
    if (telemetry_.thermal_valid) {
      telemetry_.thermal = observer_.estimate();
    }
  } else {
    ++telemetry_.estimates_gated;
  }
  report(last_estimate_, out);
}

void DriveController::hold_estimate(const EventEstimate& e) {
  if (held_count_ == kHeldEstimates) {
    // Full (events closer together than their dates lie ahead): the oldest goes now.
    fuse_held_now(0);
    remove_held(0);
  }
  held_[held_count_] = e;
  // Its date on the filter's clock: the last update was thermal_elapsed_s_ before now.
  held_left_s_[held_count_] = e.measured_at_s - e.time_s + thermal_elapsed_s_;
  ++held_count_;
}

void DriveController::fuse_held_estimate(double dt_s) {
  std::size_t due = held_count_;
  for (std::size_t i = 0; i < held_count_; ++i) {
    held_left_s_[i] -= dt_s;
    if (held_left_s_[i] <= 0.0 && (due == held_count_ || held_left_s_[i] < held_left_s_[due])) {
      due = i;  // the earliest date among those that have come
    }
  }
  // One a step's report (last_estimate()): a step that reported another leaves it to the next
  // update.
  if (due == held_count_ || last_estimate_) {
    return;
  }
  const EventEstimate e = held_[due];
  const double age_s = -held_left_s_[due];
  remove_held(due);
  fuse_estimate(e, age_s);
}

void DriveController::drop_held_estimates() {
  telemetry_.estimates_dropped_at_restart += static_cast<std::uint32_t>(held_count_);
  held_count_ = 0;
}

void DriveController::fuse_held_now(std::size_t i) {
  // Referred back to now by the model's rate of warming, as far as its date lies ahead of now.
  EventEstimate e = held_[i];
  const double ahead_s = std::max(held_left_s_[i] - thermal_elapsed_s_, 0.0);
  if (ahead_s > 0.0) {
    e.rs_ohm = referred_back_ohm(e.rs_ohm, ahead_s);
    e.measured_at_s -= ahead_s;
    e.measured_from_s = e.measured_to_s = e.measured_at_s;  // (referred: no longer on its line)
  }
  fuse_estimate(e, std::max(-held_left_s_[i], 0.0));
}

void DriveController::remove_held(std::size_t i) {
  for (std::size_t j = i + 1; j < held_count_; ++j) {
    held_[j - 1] = held_[j];
    held_left_s_[j - 1] = held_left_s_[j];
  }
  --held_count_;
}

void DriveController::update_magnet(const EventEstimate& e, const Calibration& cal) {
  // Eq. 3's Ke referred to its calibrated value: the flux falls by |alpha_m| per degree.
  const double magnet_C =
      cal.t0_C + (e.ke_V_s_per_rad / cal.ke0_V_s_per_rad - 1.0) / config_.magnet_coefficient_per_C;
  // The measurement's variance: the pairs' scatter averaged over the event's pairs, and the
  // part they share (the event's Rs and Vx errors through <iq> and <Gq>), in degrees.
  // (The pooled scatter is relative to Ke0; a hot magnet's Ke is smaller by (Ke/Ke0).)
  const double ke_ratio = e.ke_V_s_per_rad / cal.ke0_V_s_per_rad;
  const double shared_rel = e.ke_shared_std_V_s_per_rad / cal.ke0_V_s_per_rad;
  const double rel_var = ke_pair_rel_var() * ke_ratio * ke_ratio / std::max(e.ke_pairs, 1) + shared_rel * shared_rel;
  const double alpha = config_.magnet_coefficient_per_C;
  const double r = rel_var / (alpha * alpha);
  const double sys = std::abs(e.ke_systematic_std_V_s_per_rad / (cal.ke0_V_s_per_rad * alpha));  // a std, C
  // A measurement no magnet can give (not a number, outside what any NdFeB grade survives or
  // any ambient reaches), or one far outside the filter's band (the band, the measurement's
  // own error bar and both systematic parts, 6 sigma together), is counted and refused, never
  // averaged in. An estimate that aged out is still the prior (its variance grown with its
  // age); only a new Ke0 (or none yet) starts afresh.
  const bool physical = std::isfinite(magnet_C) && std::isfinite(r) && std::isfinite(sys) &&
                        magnet_C >= kMagnetPlausibleMin_C && magnet_C <= kMagnetPlausibleMax_C;
  const double prior_var = magnet_var_now_C2();
  const bool has_prior = magnet_measured_ && !magnet_reset_;
  const bool consistent =
      !has_prior || std::abs(magnet_C - magnet_filtered_C_) <=
                        kMagnetGateSigma * std::sqrt(prior_var + magnet_sys_std_C_ * magnet_sys_std_C_ + r + sys * sys);
  if (!physical || !consistent) {
    ++telemetry_.magnet_rejected;
    const bool finite = std::isfinite(magnet_C) && std::isfinite(r) && std::isfinite(sys);
    telemetry_.magnet_last_refusal = {
        !finite ? MagnetRefusal::kNotANumber : !physical ? MagnetRefusal::kImplausible : MagnetRefusal::kInconsistent,
        magnet_C, magnet_filtered_C_, std::sqrt(prior_var + magnet_sys_std_C_ * magnet_sys_std_C_ + r + sys * sys)};
    return;
  }
  pool_ke_scatter(e, cal.ke0_V_s_per_rad);
  if (has_prior) {
    // A scalar Kalman filter (random walk between measurements: magnet_var_now_C2). The
    // systematic part follows the estimate with the same gain (the readings' systematic
    // errors taken as correlated): a reading the filter weighs little changes it little.
    const double k = prior_var / (prior_var + r);
    magnet_filtered_C_ += k * (magnet_C - magnet_filtered_C_);
    magnet_var_C2_ = (1.0 - k) * prior_var;
    magnet_sys_std_C_ = (1.0 - k) * magnet_sys_std_C_ + k * sys;
  } else {
    magnet_filtered_C_ = magnet_C;  // the first measurement against this Ke0
    magnet_var_C2_ = r;
    magnet_sys_std_C_ = sys;
    magnet_reset_ = false;
  }
  magnet_valid_ = true;
  magnet_measured_ = true;
  magnet_age_s_ = -thermal_elapsed_s_ * observer_.time_scale();  // magnet_age_now_s() = 0
  telemetry_.magnet_valid = true;
  telemetry_.magnet_C = magnet_filtered_C_;
  publish_magnet_std();  // at age 0: the bar as this measurement leaves it
  magnet_upper_C_ = magnet_filtered_C_ + config_.derating.confidence_sigma * telemetry_.magnet_std_C;
  telemetry_.magnet_upper_C = magnet_upper_C_;
}

double DriveController::calibration_ke0_std(double ke0) const {
  // Ke0's standard error: the larger of the calibration events' own scatter (each event the
  // mean of its pairs; three events or more) and the pooled pair scatter over all their pairs,
  // plus what the events share and their scatter cannot show (one operating point, one Vx
  // prior: the mean of their Rs/Vx and bridge-model variances, not divided by N).
  const double n = calibration_ke_count_;
  if (n < 1.0) {
    return 0.0;  // unknown: magnet_ke0_var_C2() assumes kUnknownKe0StdFraction
  }
  double var = 0.0;
  if (n >= 3.0) {
    var = std::max(0.0, (calibration_ke_sq_sum_ - n * ke0 * ke0) / (n - 1.0)) / n;
  }
  if (calibration_ke_pairs_ > 0 && ke_pooled_dof_ > 0.0) {
    var = std::max(var, ke0 * ke0 * ke_pooled_rel_var_sum_ / ke_pooled_dof_ / calibration_ke_pairs_);
  }
  var += calibration_ke_model_var_sum_ / n;
  const double std = std::sqrt(var);
  return std::isfinite(std) ? std : 0.0;
}

void DriveController::start_thermal_from_guess(double guess_C) {
  observer_.restart_unknown(guess_C);  // keeps the observer's configuration, time scale included
  thermal_guess_pending_ = false;
  thermal_restored_ = false;  // the model's rise starts from 0 at a guess
  nameplate_excess_C_ = 0.0;
}

void DriveController::restore_thermal_state(const ThermalState& state, double downtime_s, double ambient_C) {
  drop_held_estimates();
  observer_.restore(state, downtime_s * observer_.time_scale(), ambient_C);
  thermal_guess_pending_ = false;
  thermal_restored_ = true;  // the model's rise holds the restored state's
}

void DriveController::advance_thermal(std::uint32_t periods, const DriveCommand& command) {
  // The periods' time in steps of at most one update's (a lost sample's timeout may be longer
  // than an update, and the filter's step is bounded: controller_config), each update run when
  // its time is complete.
  for (std::uint32_t left = periods; left > 0;) {
    const std::uint32_t take = std::min(left, thermal_update_periods_);
    left -= take;
    count_thermal_periods(take, command);
  }
}

void DriveController::count_thermal_periods(std::uint32_t periods, const DriveCommand& command) {
  thermal_count_ += periods;
  thermal_elapsed_s_ += static_cast<double>(periods) * config_.period_s;
  if (thermal_elapsed_s_ >= config_.thermal_update_s) {
    age_magnet(thermal_elapsed_s_);
    thermal_elapsed_s_ = 0.0;
    update_thermal(command.ambient_C, command.mode == DriveMode::kSpeed);
  }
}

void DriveController::update_thermal(double ambient_C, bool speed_mode) {
  thermal_ambient_C_ = ambient_C;
  if (thermal_guess_pending_) {
    // Nothing known about the winding yet: the ambient sensor is the best guess (a motor at
    // rest), with a wide uncertainty; the first measurement decides.
    start_thermal_from_guess(ambient_C);
  }
  const auto count = static_cast<double>(thermal_count_);
  const double dt = count * config_.period_s;
  const double i_sq = i_sq_sum_ / count;
  const double speed = speed_sum_ / count;
  observer_.predict(dt, i_sq, speed, ambient_C, thermal_enabled_count_ == 0);
  if (held_count_ > 0) {
    fuse_held_estimate(dt);
  }
  // The time-to-limit's load: a first-order average over about one injection interval (1 to
  // 10 s of drive time: a load step shows within seconds). With the last 10 ms alone the
  // prediction flickered with the pulses (docs/estimator.md section 7). Figures that are no
  // number are left out, so the average never turns NaN; the first one starts it.
  if (std::isfinite(i_sq) && std::isfinite(speed)) {
    if (load_i_sq_A2_ < 0.0) {
      load_i_sq_A2_ = i_sq;
      load_speed_rad_s_ = speed;
    } else {
      const double a = dt / (std::clamp(config_.injection.interval_s, 1.0, 10.0) + dt);
      load_i_sq_A2_ += a * (i_sq - load_i_sq_A2_);
      load_speed_rad_s_ += a * (speed - load_speed_rad_s_);
    }
  }
  i_sq_sum_ = 0.0;
  speed_sum_ = 0.0;
  thermal_count_ = 0;
  thermal_enabled_count_ = 0;

  const ThermalEstimate e = observer_.estimate();
  // dRs/dt for the scheduler: the model's warming through Eq. 1's slope at the estimate.
  // Kept finite here, where it changes, so that the step passes it on as it is (a filter
  // without an estimate yet has no rate).
  // (Eq. 1 is linear in the temperature: the resistance is the mean of the two.)
  const double rs_above = observer_.resistance_at_C(e.winding_C + 0.5);
  const double rs_below = observer_.resistance_at_C(e.winding_C - 0.5);
  const double rs_per_C = rs_above - rs_below;
  const double rate = observer_.winding_rate_C_per_s() * rs_per_C;
  rs_rate_ohm_per_s_ = std::isfinite(rate) ? rate : 0.0;
  // And the resistance itself, with its variance, for the scheduler's Lq learning; none while
  // a calibration runs, whose filter carries the old Rs0 that the calibration is replacing.
  // (Its variance without an uncalibrated Rs0's share: the resistance goes back through the
  // same Rs0, which cancels that error.)
  scheduler_.set_winding_resistance(calibrating_ ? std::numeric_limits<double>::quiet_NaN() : 0.5 * (rs_above + rs_below),
                                    observer_.measured_winding_variance_C2() * rs_per_C * rs_per_C);
  derating_ = derate(config_.derating, e);
  telemetry_.derating = derating_.derating;
  // The magnets' limit, on the last magnet estimate even after it aged out (no longer
  // published as valid): a derated drive may inject too little to measure again (the current
  // limit leaves no room, or it turns too slowly for the EMF), and nothing models the magnets'
  // cooling, so the limit holds until a new measurement says otherwise. Like the winding's, it
  // derates on the estimate's upper bound (derating.confidence_sigma), the error bar as the
  // last measurement left it: a bar that kept growing while nothing can measure (standstill)
  // would take a drive to its floor for want of a speed. Before the first estimate there is
  // nothing to derate on. The tighter of the two limits is the drive's.
  const DeratingResult magnet = magnet_measured_ ? derate_magnet(config_.derating, magnet_upper_C_)
                                                 : DeratingResult{config_.derating.max_current_A, false};
  telemetry_.magnet_derating = magnet.derating;
  publish_magnet_std();
  derating_.current_limit_A = std::min(derating_.current_limit_A, magnet.current_limit_A);
  scheduler_.set_motoring_current_limit(derating_.current_limit_A);
  // The winding's derating limits the motoring current, for its heat. A pair's pulses may reach
  // past it, up to the drive's current limit: their heat is a small, modelled share (the
  // injection loss, Eqs. 30-32), and a derated drive is the one that most needs to measure.
  // Kept within the derated limit, every pair of a drive at its limit found no room, and the
  // filter, blind while derating on T + k sigma with a growing sigma, held the current low for
  // good (docs/estimator.md §2, the guards). The magnets' derating binds the pulses too: a -F
  // pulse at hot magnets is the demagnetising current that limit is there for.
  injection_current_limit_A_ = magnet.current_limit_A;
  telemetry_.thermal = e;
  telemetry_.thermal_valid = true;
  telemetry_.current_limit_A = derating_.current_limit_A;
  // Time-to-limit is slower to compute; every tenth update is plenty. Its limit is the derating
  // threshold (DRIVE_STATUS TimeToLimit): the time until the drive starts to take current away,
  // i.e. until the upper bound it derates on, T + k sigma, reaches derating.start_C (with the
  // present sigma), 0 once it derates. (Until 2026-11-29 it was derating.limit_C, the floor's
  // temperature, which a derating drive seldom reaches: the prediction said "never" under a load
  // that derated 10 s later.)
  // Under speed control the load continues as a torque: as the housing and the magnets with it
  // warm, the flux falls by beta per kelvin of magnet, the speed loop answers the torque lost
  // with current, and the copper loss grows with 1/flux^2, relative to the flux at the magnets'
  // present temperature (their estimate, else the housing's: the rotor follows the housing).
  // Without it the prediction held the present current and came late by up to twice the time
  // remaining (docs/estimator.md section 7, "Time-to-limit, measured"). In torque mode the
  // reference current is the torque over the commissioned kt: the current holds and the shaft's
  // torque falls instead, so the loss is held. (A magnet coefficient above zero would make the
  // current fall; the gain is then 0, the earlier, safe answer.)
  if (++thermal_updates_ % 10 == 0) {
    double t = 0.0;
    const double threshold_C = config_.derating.derate_start_C - config_.derating.confidence_sigma * e.winding_std_C;
    const double beta = config_.magnet_coefficient_per_C;
    const double magnet_C = magnet_measured_ ? magnet_filtered_C_ : e.housing_C;
    const double flux = std::max(1.0 + beta * (magnet_C - observer_.calibration().t0_C), 0.1);
    const double loss_per_housing_C = speed_mode ? -2.0 * beta / flux : 0.0;
    telemetry_.time_to_limit_valid =
        load_i_sq_A2_ >= 0.0 && observer_.time_to_limit_s(threshold_C, load_i_sq_A2_, load_speed_rad_s_, ambient_C, &t,
                                                          loss_per_housing_C);
    telemetry_.time_to_limit_s = telemetry_.time_to_limit_valid ? t : 0.0;
  }
}

double DriveController::present_flux_linkage_Wb() const noexcept {
  // Ke0 (Eq. 3's, per mechanical rad/s: p psi) at the calibration's T0, else the commissioned
  // flux at the motor's reference temperature. A magnet estimate only while it is valid: one
  // aged out is held for the derating's safety, not for a reading (the housing's is fresher).
  const Calibration& cal = observer_.calibration();
  const bool calibrated = cal.ke0_V_s_per_rad > 0.0;
  const double psi0 = calibrated ? cal.ke0_V_s_per_rad / config_.motor.pole_pairs : config_.current.flux_linkage_Wb;
  const double psi0_at_C = calibrated ? cal.t0_C : config_.motor.rs_reference_temp_C;
  const double magnet_C = magnet_valid_ ? magnet_filtered_C_
                          : telemetry_.thermal_valid && std::isfinite(telemetry_.thermal.housing_C) ? telemetry_.thermal.housing_C
                                                                                                    : psi0_at_C;
  return psi0 * std::max(1.0 + config_.magnet_coefficient_per_C * (magnet_C - psi0_at_C), 0.1);
}

// A period without a usable sample (lost, implausible, a latched fault): the safe output.
const DriveOutput& DriveController::step_without_sample(double now, std::uint32_t periods, const DriveCommand& command) {
  // No fresh sample: the safe output for this period, and the pair in progress is lost.
  output_ = {};
  was_enabled_ = false;
  have_previous_ = false;
  // The shaft may turn on meanwhile (a coasting load): unless the next usable sample follows
  // the tracker's last one (DriveInput::continuous), its angle and speed are no longer the
  // rotor's (below). (The power-up's samples, unusable until the sensors' offsets are known,
  // find the tracker not yet started.)
  angle_gap_ = angle_gap_ || angle_.initialised();
  // Nothing drives the winding now, but it keeps cooling, and a latched OVERTEMPERATURE must
  // see it cool to clear: the thermal model runs on at rest (no current, no speed), at the
  // real time the step stands for (advance_thermal). Not before
  // the drive has run: the power-up's first samples are not an outage, and before the model
  // ever ran there is nothing to carry on.
  // A fault or a lost sample does not stop the clock of the magnet's estimate: the thermal
  // updates age it, or else it is aged here.
  if (angle_gap_ && telemetry_.thermal_valid) {
    advance_thermal(periods, command);
  } else {
    age_magnet(static_cast<double>(periods) * config_.period_s);
  }
  if (sweep_.active()) {
    sweep_.abort();
    finish_inverter_sweep(now);
  }
  if (check_.active()) {
    const bool measuring = !check_.decided();
    check_.abort();
    if (measuring) {
      finish_angle_check();
    }
  }
  pending_angle_jump_rad_ = 0.0;  // the history starts afresh (have_previous_)
  telemetry_.inverter_sweep_active = false;
  telemetry_.angle_check_active = false;
  clear_motoring_telemetry();
  telemetry_.voltage_limited = false;  // the bridge is off: nothing limits its voltage
  SchedulerInput s;
  s.time_s = now;
  const SchedulerOutput& so = scheduler_.step(s, nullptr);
  if (so.completed) {
    handle_pair(*so.completed);
  }
  if (so.estimate) {
    handle_estimate(*so.estimate);  // an event the loss ended: reported and counted like any
  }
  publish_learned_if_moved();  // (an event's Vx carried, a failed calibration's restored)
  return output_;
}

// The angle check's and the bridge sweep's share of a period, which step() runs only while either
// runs or waits to start: their restarts, their ends on the voltage limit, the check's step and the
// sweep that follows it.
void DriveController::check_and_sweep_period(double now, bool enabled, bool speed_controlled, const Dq& i, double omega_e) {
  if (check_restart_.pending) {
    // The calibration's angle check, aborted or voided, starts again as the sweep does (below).
    if (!calibrating_) {
      check_restart_.pending = false;
    } else if (check_restart_.due(enabled, config_.period_s, kSweepHoldoff_s)) {
      check_.start(config_.angle_check, angle_check_motor(), config_.period_s);
    }
  }
  // The check's and the sweep's levels run on top of the held motoring point. In field
  // weakening a positive level takes back part of the weakening the held d current does, and
  // above the id = 0 speed the current loop loses the machine to its EMF: a newcomer's servo
  // calibrating at 600 rad/s tripped 5 ms into the angle check's first level
  // (docs/estimator.md section 6.1). There each ends before its first level as voltage-limited,
  // as it would have at it; the calibration's events then wait for headroom, as at the voltage
  // limit, and its timeout says so. A positive level held on the voltage limit ends too, at any
  // speed (held_on_voltage_limit).
  if ((check_.starting() && field_weakened()) || (held_on_voltage_limit() && check_.id_ref_A() > 0.0)) {
    check_.stop(AngleCheckOutcome::kVoltageLimited);
    finish_angle_check();
  }
  if (check_.active() &&
      check_.step(enabled, speed_controlled, i.d, i.q, angle_.mechanical_speed_rad_s(), omega_e,
                  flags_now_.limited)) {
    finish_angle_check();
  }
  if (sweep_after_check_ && !check_.active()) {
    sweep_after_check_ = false;
    if (calibrating_) {
      start_calibration_sweep(now);
    }
  }

  if (sweep_restart_.pending) {
    // The calibration's sweep, aborted by a stop, a lost sample or a settling speed, or
    // unresolved, starts again once the drive has run kSweepHoldoff_s (kSweepAttempts); the
    // calibration's events wait for it as before. A calibration that ended wants no sweep.
    if (!calibrating_) {
      sweep_restart_.pending = false;
    } else if (sweep_restart_.due(enabled, config_.period_s, kSweepHoldoff_s)) {
      sweep_.start(config_.inverter_sweep, config_.period_s);
    }
  }
  if ((sweep_.starting() && field_weakened()) || (held_on_voltage_limit() && sweep_.id_ref_A() > 0.0)) {  // (as the check's)
    sweep_.stop(InverterSweepOutcome::kVoltageLimited);
    finish_inverter_sweep(now);
  }
}

const DriveOutput& DriveController::step(const DriveInput& in, const DriveCommand& command) {
  if (reported_) {  // (six optionals asked one by one cost a dozen instructions a step)
    last_pair_.reset();
    last_estimate_.reset();
    last_event_.reset();
    calibration_done_.reset();
    magnet_reference_done_.reset();
    sweep_done_.reset();
    check_done_.reset();
    reported_ = false;
  }
  // (A calibration refused as it was asked for, before this step, is this step's news.)
  calibration_failed_now_ = std::exchange(calibration_refused_on_request_, false);
  const double now = static_cast<double>(period_) * config_.period_s;
  const std::uint32_t periods = std::max<std::uint32_t>(in.periods, 1U);
  period_ += static_cast<std::int64_t>(periods);

  const bool usable = controllable(in);
  if (!usable) {
    return step_without_sample(now, periods, command);  // (out of line: the common period's registers)
  }

  const bool after_lost = periods > 1U;
  if (angle_gap_ || after_lost || !angle_.speed_known()) {
    // After unusable steps (an outage, a latched fault), a sample that does not follow the
    // tracker's last one finds the shaft turned by an unknown angle: with the old state, a shaft
    // that turned on for 20 ms at 157 rad/s looked like a step of half a turn, read by the PLL
    // as thousands of rad/s. The tracker starts afresh (this sample locates the rotor, the next
    // gives its speed) and the bridge stays off until then (angle_lost_). The same while it
    // seeds its speed: a sample lost between the two would double it. A sample that does follow
    // (a lockstep power stage slower than the sample timeout) continues the tracker as it is.
    if ((angle_gap_ || (angle_.initialised() && !angle_.speed_known())) && !in.continuous) {
      angle_lost_ = true;
      angle_.reset();
    }
    angle_gap_ = false;
    // A sample that follows lost ones (DriveInput::periods, the sample continuous): the
    // tracker's prediction runs on over them (or, while it has no speed yet, it starts afresh),
    // and no period sample spans the gap.
    if (after_lost) {
      if (angle_.speed_known()) {
        angle_.skip(periods - 1U);
      } else {
        angle_.reset();
        angle_lost_ = true;
      }
      have_previous_ = false;
    }
    angle_.update(in.encoder_count);
    angle_lost_ = angle_lost_ && !angle_.speed_known();
  } else {
    // The common period: the tracker has its speed and nothing came between (angle_lost_ is
    // false whenever the tracker has its speed: it is cleared by the update that gives it).
    angle_.update(in.encoder_count);
  }
  const bool enabled = command.mode != DriveMode::kDisabled && !angle_lost_;
  const double theta = angle_.electrical_angle_rad();
  const double omega_e = angle_.electrical_speed_rad_s();
  const double theta_smooth = angle_.smooth_unwrapped_electrical_angle_rad();
  // The rotor-frame rotation of this sample; those of later instants follow by composing it
  // with the rotation of half a period (below): two sincos a period, not four.
  const Rotation at_sample = rotation(theta);
  const Dq i = park(clarke(in.i_A), at_sample.c, at_sample.s);

  if (pending_angle_jump_rad_ != 0.0) {
    // An angle correction made since the history was taken (the check's, inside the last step;
    // restore_angle's, between steps): the history moves with it.
    previous_theta_smooth_ += pending_angle_jump_rad_;
    pending_angle_jump_rad_ = 0.0;
  }
  const double smooth_advance = have_previous_ ? theta_smooth - previous_theta_smooth_ : 0.0;

  // The calibration's angle check and bridge sweep, running or waiting to start: in almost every
  // period neither is, and this one test stands for the dozen that would each find them idle (an
  // idle check or sweep has no level, does not start and does not step; each starts only in
  // check_and_sweep_period or in start_calibration, between steps). About 30 instructions of the
  // nominal step (docs/performance.md).
  const bool check_or_sweep =
      check_restart_.pending || sweep_restart_.pending || sweep_after_check_ || check_.active() || sweep_.active();
  if (check_or_sweep) {
    check_and_sweep_period(now, enabled, command.mode == DriveMode::kSpeed, i, omega_e);
  }

  // The measured bus's distance from the one Vx is referred to (0 without one).
  const double bus_offset_V = vx_referred_to_bus_ ? in.vdc_V - config_.vx_reference_bus_V : 0.0;
  // The period that just ended, [k-1, k]: its voltage was commanded two steps ago. Built only
  // for a reader: the scheduler's recording phases (InjectionScheduler::records) or the
  // no-injection baseline; the rest of a pair and the time between events need none (about a
  // sixth of a step's instructions, docs/performance.md). The bridge sweep needs only the
  // period's middle angle and ends' mean current.
  const bool baseline_reads =
      config_.estimator == EstimatorKind::kNoInjection && enabled && !(check_or_sweep && (sweep_.active() || check_.active()));
  const double sample_theta = 0.5 * (previous_theta_smooth_ + theta_smooth);  // the period's middle
  const bool scheduler_reads = config_.estimator == EstimatorKind::kInjection && scheduler_.records(sample_theta);
  const PeriodSample* sample = nullptr;  // period_sample_ once built
  if (have_previous_ && (baseline_reads || scheduler_reads || (check_or_sweep && sweep_.active()))) {
    // The rotor's frame at the period's middle: the sample's angle less half the encoder's
    // advance over the period (no second sincos). The rotor's, not the PLL's: the smooth angle
    // lags the rotor by a / wn^2 under an acceleration a, and a pulse's own reluctance torque
    // accelerates a light salient rotor by opposite amounts in a pair's two recordings. On the
    // 1.5 kW servo (Lq - Ld = 1 mH, 5e-4 kg m^2) that lag, some 0.016 rad, turned the bridge's
    // sign pattern by it, Vx dGd took Vx Gq times it, and every estimate read 2 % low
    // (docs/accuracy.md, "A light salient servo"). The encoder's quantisation leaves half a
    // count of noise, which averages out.
    const Rotation at_mid = compose(at_sample, small_rotation(-0.5 * angle_.last_step_electrical_rad()));
    const Dq ends_mean{0.5 * (previous_i_A_.d + i.d), 0.5 * (previous_i_A_.q + i.q)};
    // The period's command in the rotor's frame at its middle. It was rotated two steps ago to
    // the angle that sample and the PLL's speed predicted, 1.5 periods on, and is kept in the
    // stator's frame: projected here by the rotor's angle, not by that prediction. A PLL speed
    // that lags a pulse's transient left the command that far off the rotor's d axis, where
    // w psi_q (the EMF) is the largest voltage there is: 1e-3 rad at 110 V is 0.11 V in Vd, the
    // size of the servo's bias without its dead time (ibid.). An angle correction needs
    // nothing: the stator's frame does not move with it.
    const Dq v_mid = park(v_applied_now_ab_, at_mid.c, at_mid.s);
    if (baseline_reads || scheduler_reads) {
      // Filled in place, every field (the member is reused: neither zero-filled nor copied).
      PeriodSample& s = period_sample_;
      sample = &period_sample_;
      s.time_s = now - 0.5 * config_.period_s;
      s.theta_e_rad = sample_theta;
      // The period's mean speed, from the encoder's advance over it: what the period's mean
      // voltage carries (w psi_q, the EMF). The PLL's speed lags the transient that a pulse's
      // own torque makes on a light rotor, by opposite amounts in a pair's two recordings, and
      // Eq. 37's Lq iq dw term read that lag as resistance: -0.56 % on the 48 V servo, the
      // reference's 20 seeds +0.58 C of mean (docs/estimator.md 5.4).
      s.omega_e_rad_s = angle_.last_step_electrical_rad() / config_.period_s;
      s.omega_m_rad_s = angle_.mechanical_speed_rad_s();
      s.di_dt_A_s = {(i.d - previous_i_A_.d) / config_.period_s, (i.q - previous_i_A_.q) / config_.period_s};
      const PeriodPattern pattern =
          dead_time_pattern(previous_i_abc_A_, in.i_A, config_.dead_time.current_band_A,
                            // the correction is first order in noise / band: never more than a quarter
                            std::min(pattern_noise_A_, 0.25 * config_.dead_time.current_band_A), at_mid);
      // The period's means as the machine saw them: the stator-fixed command and bridge error,
      // turned back across the period, shrink; the current bends (machine_equations.hpp).
      const double shrink = period_voltage_shrink(smooth_advance);
      s.dead_time_pattern = period_sign_pattern(pattern.mean, pattern.moment, smooth_advance);
      // The bridge's error beyond the one at the reference bus (DriveConfig::vx_reference_bus_V)
      // taken out, so that Vx is the error at that bus: the compensation's dead-time share of the
      // bus and what the estimator has learned it misses (InjectionConfig::vx_bus_slope_std).
      const double bus_error_V = (vx_bus_slope_ + scheduler_.vx_bus_slope()) * bus_offset_V;
      s.v_V = {shrink * v_mid.d - bus_error_V * s.dead_time_pattern.d, shrink * v_mid.q - bus_error_V * s.dead_time_pattern.q};
      const double vx = scheduler_.vx_V();
      s.i_A = period_mean_current(ends_mean, {i.d - previous_i_A_.d, i.q - previous_i_A_.q},
                                  {s.v_V.d - vx * s.dead_time_pattern.d, s.v_V.q - vx * s.dead_time_pattern.q},
                                  pattern.moment, vx, smooth_advance, config_.period_s,
                                  {config_.current.rs_ohm, config_.current.ld_H, config_.current.lq_H});
      s.voltage_limited = flags_now_.limited;
      s.modulation_clipped = flags_now_.clipped;
      if (baseline_reads) {
        baseline_.add(s);  // not on the sweep's d-axis levels: they are not motoring
      }
    }
    // The bridge sweep sees the measured currents, as the estimator does: at speed they carry
    // the EMF harmonics' ripple, which moves the zero crossings (a pattern built from the
    // reference read Vx 6 % low there). It builds its own mid-angle pattern from them and takes
    // the period's command (in the rotor's frame at the period's middle, as the pattern) and the
    // ends' mean current as they are, without the period's averages (the shrink and the
    // current's bend): its fit stays consistent in itself. It runs where the calibration does,
    // turning slowly (60 rad/s on the reference, 0.024 rad a period), not at standstill; which
    // frame its command is taken in draws each reference seed's calibration anew
    // (docs/accuracy.md, thirteenth session).
    if (check_or_sweep && sweep_.active() &&
        sweep_.step(enabled, in.i_A, at_mid, v_mid.d, ends_mean.d, omega_e, flags_now_.limited)) {
      finish_inverter_sweep(now);
    }
  }

  const bool loop_ran = was_enabled_;  // the current loop's status is last period's command
  if (enabled && !was_enabled_) {
    current_.reset();
    motoring_voltage_periods_ = 0;
    torque_demand_Nm_ = 0.0;  // the speed loop starts from it (speed_loop_started_)
    voltage_limited_since_speed_step_ = false;
    speed_loop_started_ = false;
  }
  was_enabled_ = enabled;

  // A sweep waiting to start again holds the calibration's events back as a running one does.
  const bool sweeping =
      check_or_sweep && (sweep_.active() || sweep_restart_.pending || check_.active() || check_restart_.pending);
  const bool levels = check_or_sweep && (sweep_.active() || check_.active());  // a sweep's or a check's level
  Dq motoring{};
  bool motoring_settling = false;  // (SchedulerInput::motoring_settling)
  bool release_motoring = false;   // (SchedulerInput::release_motoring)
  if (enabled) {
    // Field weakening on the last period's command (reset with the current loop on enabling:
    // its limit reads 0 until the first period), held while a pair records or the sweep and
    // the angle check run: their separations take the motoring point as still.
    if (field_weakening_.enabled()) {
      motoring_settling = weaken_field(levels, omega_e, release_motoring);
    }
    if (sweeping) {
      motoring_voltage_periods_ = 0;  // the sweep's and the check's levels are not motoring
    } else if (scheduler_.phase() == SchedulerPhase::kIdle && loop_ran) {
      track_motoring_voltage(now, omega_e);
    }
    motoring = motoring_reference(command);
  } else {
    field_weakening_.reset();
    clear_motoring_telemetry();
  }
  if (levels && enabled) {
    // The bridge sweep's or the angle check's level, on top of id = 0 control, inside the
    // drive's current limit.
    const double limit = derating_.current_limit_A;
    motoring.d += std::clamp(sweep_.id_ref_A() + check_.id_ref_A(), -limit, limit);
  }
  SchedulerInput si;
  si.time_s = now;
  si.theta_e_rad = theta_smooth;
  si.omega_e_rad_s = omega_e;
  si.motoring_ref_A = motoring;
  si.voltage_limit_V = current_.voltage_limit_V(in.vdc_V);
  si.current_limit_A = injection_current_limit_A_;
  si.motoring_settling = motoring_settling;
  // A positive pulse held on the voltage limit ends too, field weakening or not.
  si.release_motoring = release_motoring || (held_on_voltage_limit() && telemetry_.injection_A.d > 0.0);
  si.rs_rate_ohm_per_s = rs_rate_ohm_per_s_;  // finite (update_thermal)
  si.bus_offset_V = bus_offset_V;
  si.enabled = enabled && config_.estimator == EstimatorKind::kInjection && !sweeping && !after_lost;
  if (calibrating_ && !sweeping && now - calibration_started_s_ > config_.calibration_timeout_s) {
    if (config_.calibration_min_events > 0 && calibration_count_ >= config_.calibration_min_events) {
      // Some of its events before it could measure no more (a load came, the speed left the
      // range): Rs0 from those, with their larger standard error, and the same refusals as a
      // whole calibration. A nameplate's Rs0 is off by a few per cent (ten kelvin and more); a
      // few of the calibration's own events are good to a fraction of that (docs/estimator.md
      // section 6, "A calibration cut short").
      complete_calibration();
    } else {
      // Too few usable events in time (the method cannot inject here, or every pair was
      // rejected): keep the stored calibration and say so.
      fail_calibration(CalibrationFailure::kTimeout);
    }
  }
  si.request_now = command.request_injection || (calibrating_ && enabled);
  const SchedulerOutput& so = scheduler_.step(si, sample);
  if (so.completed && so.completed->outcome == PairOutcome::kAborted && enabled && field_weakening_.enabled()) {
    hand_pulse_over(motoring);
  }
  if (so.completed) {
    handle_pair(*so.completed);
  }
  if (so.estimate) {
    handle_estimate(*so.estimate);
  }

  Dq v{};
  AlphaBeta v_total{};  // in the stator's frame
  bool limited = false;
  bool clipped = false;
  if (enabled) {
    const Dq i_ref{motoring.d + so.injection_A.d, motoring.q + so.injection_A.q};
    const CurrentControllerStatus& cs = current_.step(i_ref, i, omega_e, in.vdc_V);
    v = cs.v_V;
    limited = cs.voltage_limited;
    // The command is applied during the next period: rotate it to the angle at that period's
    // middle (1.5 periods of rotation ahead) and compensate the dead time for the currents
    // expected then.
    const Rotation half = small_rotation(0.5 * omega_e * config_.period_s);
    const Rotation one = compose(half, half);
    const Rotation at_start = compose(at_sample, one);       // theta + 1 period of rotation
    const Rotation at_apply = compose(at_start, half);       // theta + 1.5 periods
    const Rotation at_end = compose(at_start, one);          // theta + 2 periods
    const double c = at_apply.c;
    const double sn = at_apply.s;
    // The currents expected at the start and end of that period: the reference, turning.
    const Abc i_start = inverse_clarke(inverse_park(i_ref, at_start.c, at_start.s));
    const Abc i_end = inverse_clarke(inverse_park(i_ref, at_end.c, at_end.s));
    const Abc correction = dead_time_compensation_V(i_start, i_end, config_.dead_time, in.vdc_V, config_.period_s);
    const AlphaBeta v_ab = inverse_park(v, c, sn);
    const Duties d = svpwm_corrected(v_ab, in.vdc_V, correction);
    output_.duty = d.value;
    // The duties are clamped to [0, 1] or NaN (a NaN passes the clamp): their sum is finite
    // exactly when each one is.
    if (!std::isfinite(d.value[0] + d.value[1] + d.value[2])) {
      // Never a plausible-looking command from an implausible computation: gates off, and
      // the caller latches the fault.
      output_ = {};
      output_.fault = true;
    } else {
      output_.enable = true;
      output_.fault = false;
    }
    // What the bridge was asked for in total: the current controller's voltage plus the
    // compensation. The estimator models the bridge's whole error against this (see
    // pair_estimator.hpp), so it must see the compensation actually applied.
    const AlphaBeta comp = clarke(correction);
    v_total = {v_ab.alpha + comp.alpha, v_ab.beta + comp.beta};
    limited = limited || d.clipped;
    clipped = d.clipped;
    // Near a rail only on a low bus (pulse_lost; the constructor).
    if (!clipped && in.vdc_V < pulse_check_below_V_) {
      clipped = pulse_lost(d, correction, dead_time_error_V(config_.dead_time, in.vdc_V, config_.period_s),
                           dead_time_fraction_);
    }
    telemetry_.i_ref_A = i_ref;
    telemetry_.injection_A = so.injection_A;
  } else {
    output_ = {};
    telemetry_.i_ref_A = {};
    telemetry_.injection_A = {};
  }

  // Shift the command history: what was "next" is applied during the coming period.
  v_applied_now_ab_ = v_applied_next_ab_;
  flags_now_ = flags_next_;
  limited_periods_ = flags_now_.limited ? limited_periods_ + 1 : 0;
  v_applied_next_ab_ = v_total;
  flags_next_ = {limited, clipped};
  voltage_limited_since_speed_step_ = voltage_limited_since_speed_step_ || limited;
  previous_i_A_ = i;
  previous_i_abc_A_ = in.i_A;
  // (An angle correction made in this step moves this history at the next step's start.)
  previous_theta_smooth_ = theta_smooth;
  have_previous_ = true;

  // Thermal model at its own rate.
  const double i_sq = i.d * i.d + i.q * i.q;
  i_sq_sum_ += i_sq;
  speed_sum_ += angle_.mechanical_speed_rad_s();
  thermal_enabled_count_ += enabled ? 1 : 0;
  if (!after_lost) {
    count_thermal_periods(1U, command);  // advance_thermal without its chunking (docs/performance.md)
  } else {
    // The sample stands for the lost periods before it too.
    const auto lost = static_cast<double>(periods - 1U);
    i_sq_sum_ += lost * i_sq;
    speed_sum_ += lost * angle_.mechanical_speed_rad_s();
    advance_thermal(periods, command);
  }
  if (config_.estimator == EstimatorKind::kNoInjection && baseline_.updates() > 0 && !sweeping &&
      now - last_baseline_publish_s_ >= config_.baseline_publish_s) {
    last_baseline_publish_s_ = now;
    EventEstimate e;
    e.time_s = now;
    e.rs_ohm = baseline_.rs_ohm();
    e.rs_std_ohm = baseline_.rs_std_ohm();
    // The same plausibility window as the injection methods.
    if (!(e.rs_ohm >= config_.injection.rs_min_ohm && e.rs_ohm <= config_.injection.rs_max_ohm) ||
        !std::isfinite(e.rs_std_ohm)) {
      e.outcome = EventOutcome::kImplausible;
    }
    handle_estimate(e);
  }

  telemetry_.period = static_cast<std::uint64_t>(period_);
  telemetry_.time_s = now;
  telemetry_.theta_e_rad = theta;
  telemetry_.speed_m_rad_s = angle_.mechanical_speed_rad_s();
  telemetry_.i_A = i;
  telemetry_.v_V = v;
  telemetry_.voltage_limited = limited;
  telemetry_.injection_phase = so.phase;
  telemetry_.injection_active = so.active;
  telemetry_.inverter_sweep_active = check_or_sweep && sweep_.active();
  telemetry_.angle_check_active = check_or_sweep && check_.active();
  publish_learned_if_moved();
  return output_;
}

}  // namespace pmsm::core
