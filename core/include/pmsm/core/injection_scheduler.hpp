// The injection scheduler: when to inject, what current to inject, when to record, and what
// to make of the recordings (Sections V, VIII and X of the paper).
//
// One injection event produces one or more pairs of recordings. A pair, for the default
// fixed-magnitude bipolar method at speed:
//
//   idle -> ramp up to +F (window edge, Tw) -> settle -> record 1 over an arc ->
//   ramp down (Tw) -> ramp up to -F (Tw) -> settle -> wait until the rotor is dTheta past the
//   start of recording 1 -> record 2 over the same arc -> ramp down (Tw) -> fit -> guards
//
// Unipolar records without injection first and with injection second. Where the voltage
// leaves no room for the configured pair (at the voltage limit), a fixed-magnitude
// field-weakening pair records at -lo F and then -F, one edge between them (InjectionConfig::
// field_weakening_pairs). Fixed-angle injection
// places a windowed arc centred on theta_F (Eqs. 11-12, Fig. 9) and records the whole pulse.
// DC injection (the baseline, Eqs. 4-7) injects a stator-fixed vector over whole revolutions.
// Below a minimum speed the recordings are taken over time instead of rotor angle (there is
// no EMF to separate; what the separation still removes is the inverter's error and the
// sensor offsets).
//
// Guards (each with its own reason): total current within the limit and voltage headroom
// (Eq. 29 at the operating point) before a pair starts, reducing F or skipping; speed change
// and motoring-current change between the recordings, fit residual, conditioning and
// plausibility after it. A rejected pair never contributes to an estimate.
//
// An event runs one pair per injection level (e.g. F and 0.4 F). The inverter's
// uncompensated voltage Vx is nearly collinear with Rs within one pair, because the
// current-sign pattern barely changes along the recording; across levels the ratio of the two
// regressors changes, so the event's joint fit separates them (docs/estimator.md). Vx is a
// property of the inverter and changes slowly, so its estimate is carried from event to event
// as a prior and fused with each event's joint fit; the event's Rs is conditioned on the
// fused Vx. One estimate is published per event.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <optional>
#include <cmath>
#include <limits>
#include <string_view>

#include "pmsm/core/motor_params.hpp"
#include "pmsm/core/pair_estimator.hpp"
#include "pmsm/core/transforms.hpp"
#include "pmsm/core/window.hpp"

namespace pmsm::core {

enum class InjectionMethod : std::uint8_t { kNone, kFixedMagnitude, kFixedAngle, kDc };
enum class Separation : std::uint8_t { kBipolar, kUnipolar };

[[nodiscard]] std::string_view to_string(InjectionMethod m);
[[nodiscard]] std::string_view to_string(Separation s);

// The outcome of one pair. The CAN protocol's injection report carries the same numbering
// (hal protocol InjectionResult; a test checks they agree).
enum class PairOutcome : std::uint8_t {
  kAccepted = 0,
  kRejectedSpeedChange = 1,
  kRejectedLoadChange = 2,
  kRejectedResidual = 3,
  kRejectedVoltageHeadroom = 4,   // skipped before starting: not enough voltage
  kRejectedCurrentLimit = 5,      // skipped before starting: not enough current budget
  kRejectedImplausible = 6,       // Rs outside the plausibility window
  kRejectedVoltageSaturation = 7, // the bridge may not have applied a recorded command (PeriodSample::modulation_clipped)
  kRejectedIllConditioned = 8,    // too few samples or collinear regressors
  kAborted = 9,                   // disabled, fault or lost speed in the middle of a pair
  kSkippedTorqueDisturbance = 10, // the reluctance torque of the injection would exceed its budget
  kCount = 11,
};
[[nodiscard]] std::string_view to_string(PairOutcome o);
// A pair recorded to its end and judged by the guards and the fit: not skipped before it began
// (voltage headroom, current limit, torque budget), nor aborted.
[[nodiscard]] bool pair_judged(PairOutcome o) noexcept;

// Why a pair was aborted (PairOutcome::kAborted), for the logs and `simulate --events`.
enum class AbortCause : std::uint8_t {
  kNone = 0,
  kDisabled = 1,            // the drive disabled or faulted: the scheduler stepped not enabled
  kMotoringNeedsVoltage = 2, // held on the voltage limit, or the field weakening short of the speed
  kSpeedLost = 3,           // a pair timed by the rotor's angle with the rotor stopping or reversing
  kCurrentLimit = 4,        // the motoring current crowded the pulse past what a cut may take
  kCount = 5,
};
[[nodiscard]] std::string_view to_string(AbortCause c);

// The reference plant's bridge (the realism profile of DESIGN section 5: 1 us of dead time at
// 10 kHz on 650 V and 1 V of device drop, 7.5 V) and the 5 mV per event the estimator's Vx was
// allowed to drift there (a tuning value of the project, not a measurement), which
// InjectionConfig::vx_drift_fraction carries to other bridges as a share.
inline constexpr double kReferenceBridgeVx_V = 1.0e-6 * 1.0e4 * 650.0 + 1.0;
inline constexpr double kReferenceVxDriftFraction = 0.005 / kReferenceBridgeVx_V;

struct InjectionConfig {
  InjectionMethod method = InjectionMethod::kFixedMagnitude;
  Separation separation = Separation::kBipolar;
  double f_A = 35.0;              // requested injection magnitude (docs/estimator.md: why 35 A)
  double f_min_A = 5.0;           // after budget reduction, below this the pair is skipped
  double interval_s = 10.0;       // from the start of one event to the next
  double retry_s = 1.0;           // after a skipped event
  // From the second refusal in a row on (an event that yielded nothing), the delay to the next
  // event, the interval's or retry_s, is scaled by 1 + retry_jitter v, v drawn uniform in
  // [0, 1) from a fixed-seed generator: exact delays met a duty whose period divides them (a
  // press at 60 strokes a minute) at the phase that had refused the event, every time
  // (InjectionScheduler::refusal_jitter). Never shorter than the exact delay. 0: exact delays.
  double retry_jitter = 1.0;
  static constexpr int kMaxLevels = 4;
  std::array<double, kMaxLevels> levels{1.0, 0.4, 0.0, 0.0};  // F multipliers, one pair each
  int level_count = 2;
  double first_event_s = 1.0;     // time of the first event after start
  WindowKind window = WindowKind::kModifiedBlackman;
  double tw_s = kPaperWindowPeriod_s;  // window period (each edge)
  double settle_s = 0.005;        // after an edge, before recording (current loop settling)
  double record_arc_rad = 6.283185307179586;  // angle-based recording length (one electrical turn)
  double record_time_s = 0.05;    // time-based recording length (standstill)
  double record_min_time_s = 0.04;  // angle-based recordings last at least this (whole turns)
  bool mechanical_harmonics = true;   // dTheta a multiple of 2 pi p (mechanical harmonics) instead of 2 pi
  // ... at mechanical speeds from this on (rad/s, mechanical); slower, a mechanical turn takes
  // longer than the reference's slowest angle-based pair spans (30 electrical rad/s at p = 3:
  // 0.63 s), and dTheta is a multiple of 2 pi (n electrical turns, the fewest that hold
  // recording 1 and the transition). A mechanical harmonic of order k then moves by
  // 2 pi n k / p between the recordings, little on a machine of many poles, whose pairs would
  // otherwise span seconds (InjectionScheduler::delta_theta).
  double mechanical_harmonics_min_speed_rad_s = 10.0;
  int pole_pairs = 3;
  double min_speed_for_angle_rad_s = 30.0;  // electrical; below: time-based recordings
  int unipolar_polarity = -1;     // unipolar injects -F by default (it lowers the voltage)
  // At the voltage limit (rated speed) the configured pair has no room: the level +F (or the
  // zero level of a unipolar pair) needs more voltage than there is. A field-weakening pair
  // then records at two negative levels, -lo and -F: both lower the voltage (w Ld F comes off
  // vq), the difference still carries the resistive signal Rs (F - lo), and the EMF and the
  // motoring voltage cancel in it as in any pair (docs/estimator.md §2). Fixed-magnitude
  // injection at angle-based speeds only.
  bool field_weakening_pairs = true;
  // The lower level is at least this fraction of the upper one (and at least what takes the
  // operating point off the voltage limit), so that neither recording sits in the bridge's
  // zero-current band at light load.
  double field_weakening_low_fraction = 0.3;
  // Their recordings last at least this (whole turns). At the voltage limit the fit's
  // cross-coupling term w Lq iq turns the current sensors' noise, which the current loop
  // makes real current, into d-axis voltage at w Lq (5.2 ohm, 40 times Rs, on the reference
  // motor at rated speed), against a resistive signal Rs (F - lo) that is a third of a
  // bipolar pair's 2 Rs F: the mean of that noise over a recording falls only as 1/sqrt(T).
  double field_weakening_record_min_time_s = 0.12;
  // The sign pattern's error at those speeds, as a fraction of Vx: it enters the estimate's
  // variance (measured: docs/estimator.md §2), and a unipolar pair's, which does not cancel
  // the part of it that is even in the pulse either.
  double field_weakening_pattern_error = 0.01;
  // ... and their error apart from the bridge (commissioning errors, sensors), as a fraction
  // of Rs (measured about 0.3 %, docs/accuracy.md).
  double field_weakening_rs_error = 0.003;
  // Fixed-angle and DC injection.
  double theta_f_rad = 0.0;       // angle of the injection vector (electrical)
  double beta = 0.0;              // regulation factor (Eq. 12); 1 for DC injection
  double injection_arc_rad = 1.5707963267948966;  // theta_i, flat part of the arc
  double window_arc_rad = 0.5235987755982988;     // theta_w, each edge (widened to tw_s at speed)
  double dc_revolutions = 2.0;    // DC injection: recording length in electrical turns
  // Budget.
  double current_limit_A = 80.0;  // |i| limit shared by motoring and injection (peak)
  double headroom_margin_V = 15.0; // kept free of the voltage limit for dead-time compensation and transients
  // On a salient (interior-magnet) machine d-axis injection makes reluctance torque,
  // 3/2 p (Ld - Lq) F iq: F is reduced (or the pair skipped) so that this stays within the
  // budget. Compensating a larger F with iq instead would make the estimate hang on Lq: the
  // Lq d(w iq) term of Eq. 37 would then be many times the resistive signal. Off (0) by
  // default: on a surface-magnet machine the commissioned Ld and Lq differ only by their
  // errors, and the budget would then skip injection under load for nothing.
  double max_torque_disturbance_Nm = 0.0;
  // Within the budget, a fixed-magnitude pulse on a machine configured as salient carries the
  // q-current that holds the torque (InjectionScheduler::torque_neutral): about the budget
  // over Kt (at most twice that, where the flux guard binds), so its Lq d(w iq) stays small,
  // and the speed loop has nothing left to answer. Not in the calibration (no load).
  bool torque_neutral = true;
  // Guards.
  double max_speed_change_fraction = 0.02;
  double max_speed_change_rad_s = 3.0;   // electrical; the larger of the two limits applies
  double max_load_change_A = 1.5;
  double max_residual_V = 3.0;
  double min_condition = 1e-4;
  // Plausibility window (about -57 C to 287 C for 0.133 ohm at 25 C). These and the current
  // defaults above are Table I's; the loader scales them to the configured motor
  // (motor_relative_defaults() in motor_params.hpp).
  double rs_min_ohm = 0.09;
  double rs_max_ohm = 0.27;
  // Fit.
  bool fit_dead_time = true;      // model the inverter's uncompensated voltage Vx
  bool fit_inductance = true;     // fit Ld d(dId/dt): the inductive voltage within a recording
  double vx_initial_V = 0.0;      // prior before the first event
  double vx_initial_std_V = 3.0;
  // How far Vx may wander between events (the bridge warms and cools), one standard deviation
  // per event: a share of the Vx held, in quadrature with an absolute part. A MOSFET bridge's
  // drop is R_ds(on) I, which rises 0.4-0.7 % a kelvin; a diode's or an IGBT's about 2 mV a
  // kelvin on about 1 V; the devices' switching delays, in the dead-time share, by a fraction
  // too (the programmed dead time not at all): each goes with its own size more than with a
  // fixed voltage. The default is the reference's 5 mV at its 7.5 V bridge as a share
  // (kReferenceBridgeVx_V); absolute, the same 5 mV was 2.6 % of a 6S drone's 0.19 V bridge per
  // event (docs/estimator.md section 4).
  double vx_drift_fraction = kReferenceVxDriftFraction;
  double vx_drift_std_V = 0.0;
  // The phase-current sensors' gain errors, one standard deviation per phase as a fraction. A
  // turning rotor averages their mismatch out of every whole-turn pair (their mean gain cancels
  // in Rs / Rs0); a rotor at rest does not, and a time-based event's Rs carries
  // (1/3) sum_k g_k cos(2 theta_k) of the stop's angle: sigma / sqrt(6) of Rs (docs/estimator.md
  // section 5.7).
  double current_gain_std_fraction = 0.01;
  // Vx is the bridge's error at the reference bus; each period's voltage is referred to it by
  // the dead time the compensation assumes (DriveController, vx_reference_bus_V). What that
  // dead time misses, a slope in V of Vx per V of bus, is a second learned state with this
  // prior (0: none modelled): it shows only in events that learn Vx at different buses, and
  // until then its uncertainty times the bus's distance from the reference is the held Vx's
  // (docs/estimator.md section 4, "Vx follows the bus").
  double vx_bus_slope_std = 0.0;
  // Vx is learned only from events whose pairs reverse the current vector, i.e. whose
  // motoring |iq| stays below this fraction of the smallest F of the event: then the
  // current-sign pattern simply inverts and its plateaus carry the information. Under load
  // the injection only swings the current angle, the information sits in the sector
  // transitions at current zero crossings, where no sign model is exact, and the joint fit
  // is biased in a way its own error bar cannot show (docs/estimator.md).
  double vx_learning_max_iq_fraction = 0.5;
  double vx_min_identifiability = 0.05;  // of the event's means fit, to learn Vx from it
  // ... and only below this electrical speed. What biases a fast event's Vx goes with how far
  // the rotor turns in a control period (a 4 kHz blower at 14 periods a turn learned a wrong
  // one; a 16 kHz saw at 754 rad/s learns it right): the configuration's default is 600 rad/s,
  // or 0.06 rad a period above 10 kHz (app::kVxLearningMaxAnglePerPeriod_rad).
  double vx_learning_max_speed_rad_s = 600.0;
  double lq_H = 5.5e-3;           // the controller's model, for the Eq. 37 correction
  // The Eq. 37 correction Lq d(w iq) is exact only with the true Lq, and on a salient machine
  // under load it is not small: the speed loop answers the injection's reluctance torque
  // with a change of iq proportional to the injection, so an Lq error becomes a resistance
  // error (about w dLq (Lq - Ld) iq / psi relative to Rs: -10 % in Lq costs about 20 C on the
  // salient benchmark). Lq is therefore learned from the pairs themselves: over whole turns
  // Eq. 3 leaves <vd> = Rs <id> + Ld <dId/dt> - Lq <w iq> + Vx <Gd>, where Lq <w iq> is
  // volts under any load while the other terms are known or cancel (bipolar: <id> = 0 and
  // <Gd> = 0 by symmetry). The learned value replaces lq_H in the fits that follow.
  bool learn_lq = true;
  double lq_initial_std_fraction = 0.1;   // prior: the commissioned lq_H, +-10 %
  double lq_drift_fraction = 0.002;       // how far Lq may wander between pairs
  // Saturation: the learned secant Lq is a - b s(iq) and the incremental d psi_q / d iq is
  // a - b h(iq), h = s + iq ds/diq (LqShape). Without a flux map s is u = (iq / current_limit_A)^2,
  // the first term of any symmetric saturation curve (h = 3 u); a map of several points gives
  // s its own shape. Pairs at different loads determine b (docs/estimator.md §5.1); pairs at a
  // third load bring in a bend, a further b2 s^2 lost (incremental b2 (2 s h - s^2)). The prior
  // of b, and of b2 once it enters: 0 +- this fraction of lq_H (0: no saturation model, one Lq).
  double lq_saturation_std_fraction = 0.2;
  // The commissioned saturation, from a flux map's secant at the rated current
  // (MotorParams::lq_rated_H; 0: not known): b0 = (lq_H - lq_rated_H) / u(rated_current_A).
  // Until pairs at two loads resolve b, the fits take the incremental Lq as the learned secant
  // less b0 (h - s), 2 b0 u on the quadratic: the secant is what pairs at one load measure,
  // the gap to the incremental is what they cannot. b's prior stays 0 +- lq_saturation_std_fraction:
  // once pairs resolve the curve, the machine's own measurements decide it (a prior at b0, a
  // point of the map at the rated current, pulled the learned slope: docs/estimator.md §5.1).
  // Learning off, the curve is the commissioned one, b = b0.
  double lq_rated_H = 0.0;
  // Or the flux map's secant at several currents (MotorParams::lq_map; used where it has
  // points, in place of lq_rated_H): the map's shape (LqShape) replaces u.
  LqMap lq_map{};
  double rated_current_A = 45.1;  // peak
  double lq_learning_min_voltage_V = 1.0; // |Lq <w iq>| of a pair, to learn from it
  // Listening pairs: where the torque budget refuses every pulse (a salient machine under heavy
  // load) and no load near it has taught the saturation curve, two recordings with no pulse
  // measure the secant Lq there (learn_lq; docs/estimator.md section 5.1).
  bool lq_listening = true;
  // The rotor angle's error delta (electrical rad) the Lq learner allows for, as a standard
  // deviation around 0. An encoder off by delta puts the EMF's share c = psi delta on the
  // measured d axis: <vd> holds c <w>, which a pair at one load cannot tell from -Lq <w iq>
  // (c / iq of Lq: an encoder 0.18 deg off read a shredder's Lq 10 % high at light load, and
  // surges then fitted with that Lq read Rs 10 % off; docs/accuracy.md). c is learned as a
  // third state of the curve, h = (1, -s, -<w> / <w iq>), and the fits take c dw, not Lq, for
  // it: the incremental Lq the surges need no longer carries light load's angle error, and
  // until loads far apart tell c from Lq, the pairs' error bars carry the difference. 0: not
  // modelled (Lq takes it all). This is the prior until a rotor-angle check measures the
  // angle (set_angle_prior: the drive gives the check's result); 0 by default, because pairs at
  // one load cannot tell c from an Lq error, and a prior splits a commissioning error of Lq
  // between the two (an unloaded salient machine's Lq, 10 % low, was learned 21 % low with
  // 0.2 deg). Not on a machine configured as salient (max_torque_disturbance_Nm > 0): there the
  // angle error moves the reluctance terms too, which c does not model, and the 30 mOhm IPM's
  // heat-up read 5.0 C RMS with the state against 1.8 C without (docs/estimator.md section 5.6).
  double lq_angle_std_rad = 0.0;
  double ld_H = 5.5e-3;
  double rs_nominal_ohm = 0.133;  // for the headroom calculation
  double flux_linkage_Wb = 0.3239;

  // Whether this configuration's events can learn the bridge's voltage Vx at all: the bridge's
  // term fitted, bipolar pairs (only they reverse the current vector: a unipolar pair's first
  // recording sits at the motoring current, where the bridge's error hangs on the zero-current
  // band), and two different levels or more (one level cannot tell Rs from Vx). Such an event
  // learns it when it also runs at light load (vx_learning_max_iq_fraction) and below
  // vx_learning_max_speed_rad_s, off the voltage limit, and its levels are far enough apart
  // (vx_min_identifiability) (InjectionScheduler::event_joint_fit); the others rest on the
  // prior. The scheduler and the daemon's start-up check ask the same.
  [[nodiscard]] bool can_learn_vx() const noexcept {
    if (!fit_dead_time || separation != Separation::kBipolar) {
      return false;
    }
    const int n = level_count < kMaxLevels ? level_count : kMaxLevels;
    for (int k = 1; k < n; ++k) {
      if (levels[static_cast<std::size_t>(k)] != levels[0]) {
        return true;
      }
    }
    return false;
  }
};

// The Table I drive's DC bus, at which InjectionConfig::headroom_margin_V's default (15 V)
// holds. What the margin keeps free (the dead-time compensation's dead_time f_pwm Vdc, the
// bus's ripple and sag, the current loop's reserve) scales with the bus, so the default at
// another bus is the same share of it: the drive's configuration (finalize) and
// `pmsm-thermal budget` both take it from here.
inline constexpr double kReferenceDcBus_V = 650.0;
[[nodiscard]] inline double default_headroom_margin_V(double dc_bus_V) {
  return InjectionConfig{}.headroom_margin_V * (dc_bus_V / kReferenceDcBus_V);
}

struct SchedulerInput {
  double time_s = 0.0;
  double theta_e_rad = 0.0;       // smooth, unwrapped electrical angle now
  double omega_e_rad_s = 0.0;
  Dq motoring_ref_A{};            // the motoring current reference this period
  double voltage_limit_V = 356.0; // usable voltage now (from the DC bus)
  double current_limit_A = 80.0;  // |i| limit now (may be derated)
  bool enabled = false;           // the drive is running and healthy
  bool request_now = false;       // start an event at the next opportunity
  // The motoring point's d current is still moving (field weakening settling): no pair starts
  // until it holds still, since the pair holds it where it is for both recordings.
  bool motoring_settling = false;
  // The field weakening a pair holds no longer keeps the motoring point's voltage inside the
  // current loop's reserve (the speed moved the EMF while the regulator was held): the pair
  // ends now, aborted, its pulse handed to the regulator (DriveController::weaken_field,
  // hand_pulse_over). A pair also ends, by itself, where the motoring current and the pulse
  // together would leave current_limit_A.
  bool release_motoring = false;
  // How fast the winding's resistance changes now, as the thermal model predicts it (ohm per
  // controller second): an event's pairs lie at different times, and their joint fit refers
  // each to the event's time (finish_event).
  double rs_rate_ohm_per_s = 0.0;
  // The period's measured bus less the reference Vx is referred to (0 without one).
  double bus_offset_V = 0.0;
};

enum class SchedulerPhase : std::uint8_t {
  kIdle, kRampUp, kSettle, kRecord1, kRampDown, kWaitArc, kRecord2, kPulseWait, kFinish
};

// One pair: its outcome and diagnostics. Its Rs uses the inverter voltage known when it
// finished (the published estimate is the event's, below).
struct PairResult {
  PairOutcome outcome = PairOutcome::kAborted;
  AbortCause abort_cause = AbortCause::kNone;  // set when outcome is kAborted
  InjectionMethod method = InjectionMethod::kNone;
  Separation separation = Separation::kBipolar;
  double time_s = 0.0;
  int level_index = 0;
  double f_A = 0.0;                // magnitude actually used (after budget reduction)
  bool field_weakening = false;    // recorded at -low_level F and -F (InjectionConfig)
  double low_level = 0.0;          // that pair's lower level in units of F
  double rs_ohm = 0.0;             // only meaningful when accepted
  double rs_std_ohm = 0.0;
  // Its Rs rests on the configured guess of the inverter voltage: no event (nor the stored
  // calibration) has learned Vx yet, and the guess's uncertainty moves this Rs by more than the
  // pair's own noise (a calibration's first event; the event's fit across levels measures both).
  // Where no event ever learns Vx (a stored calibration without it, a method or a load that
  // cannot), every such pair stays so.
  bool rs_rests_on_vx_guess = false;
  double delta_omega_e_rad_s = 0.0;
  double delta_iq_A = 0.0;
  double residual_rms_V = 0.0;
  double condition = 0.0;
  std::size_t samples = 0;
  bool time_based = false;
  PairConditions conditions{};
};

// Why an event published nothing.
enum class EventOutcome : std::uint8_t {
  kPublished = 0,
  kNoAcceptedPairs = 1,   // every pair was skipped or rejected (see their reports)
  kNoFit = 2,             // the accepted pairs gave no solvable fit
  kImplausible = 3,       // the event's Rs fell outside the plausibility window
  kAborted = 4,           // interrupted (disable, fault, lost speed) before its last pair
};
[[nodiscard]] std::string_view to_string(EventOutcome o);

// The estimate of one event, from its accepted pairs.
struct EventEstimate {
  EventOutcome outcome = EventOutcome::kPublished;
  double time_s = 0.0;
  int pairs = 0;                   // accepted pairs that went into it
  // The time the estimate belongs to: its pairs' mid times weighted by their information.
  // It lies before time_s (an event lasts up to seconds while the winding warms or cools),
  // and the thermal filter fuses it there (ThermalObserver::update_resistance); or after it,
  // for a fixed-magnitude event on a motoring point in field weakening (below), and the drive
  // holds the estimate until then (DriveController::hold_estimate).
  double measured_at_s = 0.0;
  // The times the estimate extrapolates from: a pair measures Rs(t1) Id1 - Rs(t2) Id2 over its
  // recordings' times t1 and t2, which on a winding warming linearly is Rs(t) (Id1 - Id2) at
  // measured_at_s, and on a winding whose warming slows (or speeds up) is that line through
  // Rs(t1) and Rs(t2) at measured_at_s. Where measured_at_s lies beyond t2 (a field-weakening
  // pair: some 3 spacings), a winding whose warming slows reads high; the thermal filter compares
  // the estimate with the same line through its own trajectory. Their weighted means over the
  // event's pairs (as measured_at_s); both equal to measured_at_s when no line is known.
  double measured_from_s = 0.0;
  double measured_to_s = 0.0;
  double rs_ohm = 0.0;
  double rs_std_ohm = 0.0;
  // The part of rs_std_ohm that more estimates do not average away: a model error common to
  // consecutive estimates (field-weakening pairs' sign pattern, the learned Lq's uncertainty,
  // a Vx held at its prior), 0 when none is known.
  double rs_systematic_std_ohm = 0.0;
  // The share of both (a variance, ohm^2) that the bus slope's error makes of an Rs held at a
  // Vx referred to the event's bus by that slope, and its sensitivity to it (ThermalObserver's
  // BusSlopeTerm, which the winding's filter learns as a state instead): 0 for an event that
  // learned its own Vx, or where no slope is learned.
  double rs_bus_slope_var_ohm2 = 0.0;
  double bus_slope_sensitivity_ohm = 0.0;  // dRs / d(slope error), ohm per V/V
  double bus_slope = 0.0;                  // the slope the event's voltages were referred with (V/V)
  double bus_slope_var = 0.0;              // its variance
  double vx_V = 0.0;               // the fused inverter voltage after this event
  double vx_std_V = 0.0;
  bool vx_from_event = false;      // the event's own levels determined Vx (joint fit)
  double joint_condition = 0.0;    // identifiability of the event's joint (Rs, Vx) fit (MeansFit)
  bool vx_learning = false;        // the event reversed the current vector: Vx was fitted
  // How far apart the buses of its recordings lay (the largest less the smallest recording's
  // mean bus, over both recordings of every pair in its fit),
  // and whether that alone kept the event from learning Vx: each pair's voltage is referred to
  // the reference bus with the bus slope learned so far, and the slope's uncertainty times this
  // spread is what the levels may disagree by beyond the fit's own noise (finish_event). Only
  // computed for an event that would otherwise learn Vx (0 for the others).
  double bus_spread_V = 0.0;
  bool vx_refused_bus_spread = false;
  double joint_rs_ohm = 0.0;       // the joint fit before fusion (diagnostics)
  double joint_vx_V = 0.0;
  bool has_emf = false;            // angle-based pairs: the EMF constant below is meaningful
  double ke_V_s_per_rad = 0.0;     // Eq. 3's Ke from the q-axis means (see drive_controller)
  // Its error bars: the pairs' scatter (sample variance of one pair's Ke, 0 with fewer than
  // two pairs) and the part every pair shares, the fitted Rs's and Vx's errors carried through
  // the q-axis equations (<iq>/<wm> times the Rs error: large under load).
  int ke_pairs = 0;
  double ke_pair_variance = 0.0;
  double ke_shared_std_V_s_per_rad = 0.0;
  // The part more events do not average away: the bridge model's error in <Gq>'s term.
  double ke_systematic_std_V_s_per_rad = 0.0;
  double lq_H = 0.0;               // the q-axis inductance the fits use after this event
  double lq_std_H = 0.0;
};

struct SchedulerOutput {
  Dq injection_A{};                // add to the motoring current reference
  bool active = false;             // an event is in progress (injection may be zero)
  SchedulerPhase phase = SchedulerPhase::kIdle;
  std::optional<PairResult> completed;  // set in the period a pair finished or was skipped
  std::optional<EventEstimate> estimate;  // set in the period an event finished (see its outcome)
};

// The shape of the saturation curve (docs/estimator.md §5.1): the secant Lq is a - b s(iq),
// the incremental d psi_q / d iq = a - b h(iq) with h = s + iq ds/diq = s + 2 u ds/du. s is a
// function of u = (iq / current_limit_A)^2 (capped at 1.44: the curve says nothing far beyond
// the limit) through (0, 0) and the commissioned map's points, s_k = (lq_H - secant_k) / b0:
// a cubic Hermite curve whose slopes at the points are the three-point parabola's, limited so
// that a monotone map gives a monotone curve (Fritsch-Carlson), and a straight line beyond the
// last point. The incremental needs ds/du, which straight segments between the points would
// get wrong by a segment's curvature (6 % at 75 A on the 30 mOhm IPM's map, 0.15 % this way).
// b0, the commissioned b, makes s equal u at the map's last point. A map of one point
// (lq_rated_H) is the quadratic itself, s = u and h = 3 u, as is no map (b0 = 0).
class LqShape {
 public:
  struct At {
    double s = 0.0;  // the secant's shape
    double h = 0.0;  // the incremental's
    // The bend's: the secant's s^2, and its incremental d(s^2 iq)/d iq = s^2 + 2 s iq ds/diq
    // = 2 s h - s^2 (5 u^2 on the quadratic).
    [[nodiscard]] double s2() const { return s * s; }
    [[nodiscard]] double h2() const { return 2.0 * s * h - s * s; }
  };
  LqShape() = default;
  explicit LqShape(const InjectionConfig& c);
  // At a q-axis current (its sign does not matter): a bounded walk over at most kMaxPoints nodes.
  [[nodiscard]] At at(double iq_A) const;
  // The commissioned b: the secant Lq lost where s = 1. Without a map, or with one point, s = u
  // and that is the current limit; a map's s equals u at its last point and follows the map
  // elsewhere (on the 30 mOhm IPM's map s = 0.93 at the limit). 0 without saturation.
  [[nodiscard]] double b0_H() const { return b0_H_; }
  // The commissioned secant at a q-axis current, lq_H - b0 s(iq) (the curve with b = b0).
  [[nodiscard]] double commissioned_secant_H(double iq_A) const { return lq_H_ - b0_H_ * at(iq_A).s; }

 private:
  double lq_H_ = 0.0;
  double limit_A_ = 0.0;
  double b0_H_ = 0.0;
  int nodes_ = 0;  // after (0, 0); 0: the quadratic
  std::array<double, LqMap::kMaxPoints + 1> u_{};
  std::array<double, LqMap::kMaxPoints + 1> s_{};
  std::array<double, LqMap::kMaxPoints + 1> slope_{};  // ds/du at each point
};

// The commissioned saturation b0: the secant Lq lost where s = 1 (LqShape), from the flux map
// (InjectionConfig::lq_map or lq_rated_H; 0 where it is not known).
[[nodiscard]] double commissioned_lq_saturation_H(const InjectionConfig& c);

class InjectionScheduler {
 public:
  // `capacity` is the largest recording, in periods (preallocated).
  InjectionScheduler(const InjectionConfig& config, double period_s, std::size_t capacity);

  // One control period: `sample` is the period that just ended (nullptr when none). The
  // output stays valid until the next call.
  const SchedulerOutput& step(const SchedulerInput& in, const PeriodSample* sample);

  // Replaces the configuration (e.g. for a calibration run). An event in progress is
  // dropped; the inverter-voltage prior is kept, it belongs to the inverter.
  void set_config(const InjectionConfig& config);
  [[nodiscard]] const InjectionConfig& config() const { return config_; }
  [[nodiscard]] SchedulerPhase phase() const { return phase_; }
  [[nodiscard]] double next_event_s() const { return next_event_s_; }
  // Between events: no event in progress and none started (what the drive does next is
  // motoring alone until the next event begins).
  [[nodiscard]] bool between_events() const { return phase_ == SchedulerPhase::kIdle && !in_event_; }
  // No event starts from here on, by schedule or request (an event in progress carries on):
  // the simulator's twin, the same drive from the same state without injection.
  void hold_events() { held_ = true; }
  // Whether the next step() may read its sample, whose angle (PeriodSample::theta_e_rad) is
  // sample_theta_e_rad: in a recording, and in the waits before one only once the sample's angle
  // has reached it (recording 2's start, a fixed-angle pulse's arc); a pair's ramps and
  // settling and the time between events need none. The caller may leave the period's sample
  // unbuilt otherwise (on the step-cost replay the waits had 13 % of the injecting periods'
  // samples, docs/performance.md). (True also when that step will abort the pair instead.)
  [[nodiscard]] bool records(double sample_theta_e_rad) const {
    if (config_.method == InjectionMethod::kNone) {
      return false;
    }
    switch (phase_) {
      case SchedulerPhase::kRecord1:
      case SchedulerPhase::kRecord2:
        return true;
      case SchedulerPhase::kWaitArc:  // matching by angle only (time matching records at once)
        return recorder_.angle_coordinate(sample_theta_e_rad) >= origin2_;
      case SchedulerPhase::kPulseWait:
        return pulse_phase(sample_theta_e_rad) >= 0.0;
      default:
        return false;
    }
  }

  // The largest F the budget allows now, and the reason when it is below f_min.
  struct Budget {
    double f_A = 0.0;
    PairOutcome limiting = PairOutcome::kAccepted;
    bool field_weakening = false;  // a field-weakening pair fits where the configured one does not
    double low_A = 0.0;            // its lower level
  };
  [[nodiscard]] Budget budget(const SchedulerInput& in, double tw_s, double wanted_A) const;

  // The inverter voltage prior carried between events.
  [[nodiscard]] double vx_V() const { return vx_V_; }
  [[nodiscard]] double vx_std_V() const { return std::sqrt(vx_var_); }
  // The learned correction to the compensation's dead-time share of the bus (V per V), by
  // which each period's voltage is referred to the reference bus beyond the compensation's.
  [[nodiscard]] double vx_bus_slope() const { return vx_slope_; }
  [[nodiscard]] double vx_bus_slope_std() const { return std::sqrt(vx_slope_var_); }
  // The whole inverter-voltage state (Vx, its bus slope and their covariance), for a
  // calibration that puts it back when it does not complete.
  struct VxState {
    double vx_V = 0.0;
    double vx_var = 0.0;
    double slope = 0.0;
    double slope_var = 0.0;
    double cov = 0.0;
    bool learned = false;  // an event or a stored calibration gave it (not the configured guess)
  };
  [[nodiscard]] VxState vx_state() const { return {vx_V_, vx_var_, vx_slope_, vx_slope_var_, vx_cov_, vx_learned_}; }
  void set_vx_state(const VxState& s) {
    vx_learned_ = s.learned;
    vx_V_ = s.vx_V;
    vx_var_ = s.vx_var;
    vx_slope_ = s.slope;
    vx_slope_var_ = s.slope_var;
    vx_cov_ = s.cov;
    ++learned_version_;
  }
  // Vx's standard error at a bus this far from the reference (the slope's uncertainty added).
  [[nodiscard]] double vx_std_at_V(double bus_offset_V) const { return std::sqrt(vx_variance_at(bus_offset_V)); }
  // The bus offset of the last event that learned Vx (0 before one).
  [[nodiscard]] double last_learned_bus_offset_V() const { return learned_bus_offset_V_; }
  // A stored Vx, known to std_V at a bus this far from the reference, with the slope at its
  // prior: Vx at the reference carries the slope's uncertainty times that distance, and the two
  // are correlated so that at the stored bus the error is std_V again.
  void set_vx_prior_at(double vx_V, double std_V, double bus_offset_V, double slope_std) {
    const double v_b = slope_std * slope_std;
    vx_learned_ = true;
    vx_V_ = vx_V;
    vx_var_ = std_V * std_V + bus_offset_V * bus_offset_V * v_b;
    vx_cov_ = -bus_offset_V * v_b;
    vx_slope_ = 0.0;
    vx_slope_var_ = v_b;
    ++learned_version_;
  }
  // The bus slope back to its prior (a calibration learns the bridge afresh).
  void reset_vx_bus_slope(double std) {
    vx_slope_ = 0.0;
    vx_slope_var_ = std * std;
    vx_cov_ = 0.0;
    ++learned_version_;
  }
  // The thermal filter's winding resistance and its variance (at its last update; NaN: no
  // estimate yet): the ohmic part of the d-axis voltage that Lq learning takes out
  // (learn_lq).
  void set_winding_resistance(double rs_ohm, double var_ohm2) {
    winding_rs_ohm_ = rs_ohm;
    winding_rs_var_ohm2_ = var_ohm2;
  }
  // The machine's motoring voltage as the current loop commands it before its limit: the mean
  // of the command (rotor frame) and the mean of its square magnitude, over the same recent
  // periods. Given in a period with no pulse on, before step() of the same `time_s`: a pair
  // starting in that step sizes its voltage budget on them instead of on the model's Eq. 3
  // (budget()).
  void set_motoring_voltage(double time_s, const Dq& mean_V, double mean_sq_V2) {
    motoring_voltage_time_s_ = time_s;
    motoring_voltage_V_ = mean_V;
    motoring_voltage_mean_sq_V2_ = mean_sq_V2;
  }
  // Replaces the inverter-voltage prior with the configured guess (when a calibration run starts,
  // so that it learns Vx afresh): no longer a learned Vx (a stored calibration's Vx is
  // set_vx_prior_at's).
  void set_vx_prior(double vx_V, double std_V) {
    vx_learned_ = false;
    vx_V_ = vx_V;
    vx_var_ = std_V * std_V;
    vx_cov_ = 0.0;  // a new prior, independent of the bus slope learned so far
    ++learned_version_;
  }
  // The motoring's current limit as the winding's derating leaves it (the drive's thermal
  // update gives it; the pulses' own limit is current_limit_A): a shaft at rest drawing 9/10 of
  // it or more may be one the derating stalled, not one that rests, and no event is started
  // early for it (retry_at_rest_).
  void set_motoring_current_limit(double limit_A) { motoring_limit_A_ = limit_A; }
  // The bridge's ripple band in use (control.dead_time_band_A, or the one a sweep measured): a
  // pair whose q current idles inside it does not teach the Lq learner the angle's share c
  // (learn_lq).
  void set_bridge_band(double band_A) { bridge_band_A_ = band_A; }
  [[nodiscard]] double lq_H() const { return lq_H_; }   // the secant Lq at zero current
  [[nodiscard]] double lq_std_H() const { return std::sqrt(lq_p_[0][0]); }
  // The learned EMF share of the d axis, c = psi delta (InjectionConfig::lq_angle_std_rad).
  [[nodiscard]] double lq_emf_d_Wb() const { return emf_d_Wb_; }
  [[nodiscard]] double lq_emf_d_std_Wb() const { return std::sqrt(lq_p_[2][2]); }
  // What a rotor-angle check measured of the angle in use (the learner's sign: vd holds
  // psi delta w) and its standard deviation: c's prior from here on, uncorrelated with the curve
  // (a correction moves the angle, and what pairs taught c before no longer holds). Ignored
  // with learning off, on a machine configured as salient, or with a non-finite argument.
  void set_angle_prior(double delta_rad, double std_rad);
  // The saturation model's b: the secant Lq lost where s = 1, the current limit without a map (LqShape).
  [[nodiscard]] double lq_saturation_H() const { return lq_b_H_; }
  // The curve's bend b2: the secant is a - b s - b2 s^2 (learned with pairs at three loads).
  [[nodiscard]] double lq_bend_H() const { return lq_b2_H_; }
  // Whether pairs at two loads have resolved it (its variance below a quarter of its prior);
  // until then the incremental Lq is the secant less the commissioned gap 2 b0 u.
  [[nodiscard]] bool lq_saturation_resolved() const { return lq_resolved_; }
  // Listening pairs recorded to their end, and those that taught the curve.
  [[nodiscard]] std::uint32_t lq_listening_pairs() const { return listening_pairs_; }
  [[nodiscard]] std::uint32_t lq_listening_learned() const { return listening_learned_; }
  // Counts the changes of the learned Vx and Lq (and their variances): a reader that publishes
  // them copies them when this moves, not every period.
  [[nodiscard]] std::uint32_t learned_version() const { return learned_version_; }
  // The learned secant and incremental Lq at a q-axis current (the commissioned curve when
  // learning is off).
  [[nodiscard]] double lq_secant_H(double iq_A) const;
  // The q-current that keeps a salient machine's torque through a d-axis pulse, added to it
  // (where torque_neutral_pulses()).
  [[nodiscard]] Dq torque_neutral(Dq injection_A, const Dq& motoring_A) const;
  // The largest share of a pulse cut to keep it and the motoring current within the current
  // limit before the pair ends instead (step()).
  static constexpr double kMaxCut = 0.1;
  // A machine configured as salient (a torque budget) with injection.torque_neutral.
  [[nodiscard]] bool torque_neutral_pulses() const {
    return config_.torque_neutral && config_.max_torque_disturbance_Nm > 0.0;
  }
  // A salient machine's torque flux psi + (Ld - Lq) id at two d-currents, saliency_H = Ld - Lq
  // (the commissioned Ld, the learned secant Lq at the motoring iq): false where either is
  // below half the magnet's, a range the model does not hold. The torque iq (psi + (Ld - Lq) id)
  // is held when iq moves by the flux ratio (torque_neutral, unexplained_load_change_A).
  [[nodiscard]] bool salient_fluxes(double saliency_H, double id_a_A, double id_b_A, double& flux_a_Wb,
                                    double& flux_b_Wb) const;
  [[nodiscard]] double lq_incremental_H(double iq_A) const;

 private:
  [[nodiscard]] bool saturation_variance_resolved() const;
  // The part of a pair's motoring-current change delta_iq_A (recording 1 minus 2) that the
  // injection does not explain (the load-change guard's measure; amperes, >= 0; infinite for a
  // non-finite change).
  [[nodiscard]] double unexplained_load_change_A(const PairConditions& c, double delta_iq_A) const;
  // Fixed-angle: how far past the pulse's start an angle is, in the direction of rotation.
  [[nodiscard]] double pulse_phase(double theta_e_rad) const { return direction_ * (theta_e_rad - pulse_start_theta_); }
  void begin_pair(const SchedulerInput& in);
  void abort(SchedulerOutput& out, const SchedulerInput& in, AbortCause cause);
  PairResult finish_pair(const SchedulerInput& in);
  [[nodiscard]] bool listens(const SchedulerInput& in) const;
  void retry_after_listening(double now_s);
  // The speed change a pair's recordings may differ by (the speed-change guard).
  [[nodiscard]] double speed_change_limit_rad_s(const PairConditions& c) const;
  // An angle-based pair's rotor stopping or reversing.
  [[nodiscard]] bool speed_lost(const SchedulerInput& in) const {
    return !time_based_ && direction_ * in.omega_e_rad_s < 0.5 * config_.min_speed_for_angle_rad_s;
  }
  [[nodiscard]] int event_level_count() const { return std::clamp(config_.level_count, 1, InjectionConfig::kMaxLevels); }
  // The least distance in s between the curve's anchors (learn_lq).
  [[nodiscard]] double lq_lever() const { return 2.0 * kLqUnmodelledFraction / config_.lq_saturation_std_fraction; }
  static constexpr std::size_t kLqStates = 4;  // the Lq curve's state (a, b, c, b2)
  using LqCovariance = std::array<std::array<double, kLqStates>, kLqStates>;
  void add_bend_prior(LqCovariance& p) const;
  void finish_listening(const SchedulerInput& in);
  EventEstimate finish_event(const SchedulerInput& in);
  // Whether the event's estimate comes from the pairs' means (event_means_): the joint fit
  // of Rs and Vx across levels, or the fixed-Vx means of flat pulses.
  [[nodiscard]] bool event_joint_fit() const;
  // The event's sample fit with Vx held at vx_V, its Lq terms refitted (fixed-angle and DC).
  [[nodiscard]] MeansFit sample_fit_fixed_vx(double vx_V) const;
  // An event's fused Vx as the prior of the next (with the drift between events).
  [[nodiscard]] double vx_variance_at(double bus_offset_V) const;
  [[nodiscard]] double bus_change_error_ohm(const FitResult& fit) const;
  void learn_vx(double bus_offset_V, double vx_V, double var_V2);
  void drift_vx();
  [[nodiscard]] bool event_uses_means() const;
  [[nodiscard]] double rest_speed_rad_s() const;  // electrical: below it the shaft rests
  double refusal_jitter();  // the factor on the delay after a refusal (InjectionConfig::retry_jitter)
  void delay_next_event(double now_s, double jitter);  // scales the delay to next_event_s_ by it
  // The time the event's estimate belongs to: its pairs' Rs times weighted by their information
  // (their plain mean where no pair has a variance; EventEstimate::measured_at_s).
  [[nodiscard]] double event_time_s() const;
  // The accepted pairs' mean of a quantity given as its weighted and its plain sums (as
  // event_time_s() weighs their times).
  [[nodiscard]] double event_pairs_mean(double weighted_sum, double plain_sum) const;
  [[nodiscard]] FitOptions fit_options(bool fit_vx) const;
  [[nodiscard]] bool plausible(double rs_ohm, double margin_ohm) const;
  bool learn_lq(const PairConditions& c, const FitResult& fit, const SchedulerInput& in);
  // A pair's Lq term (Eq. 37: y moves by S_sec dLq_sec + S_inc dLq_inc, PairConditions) and
  // the Lq it was fitted with.
  struct LqTerm {
    LqShape::At shape{};           // the saturation curve's shape at the pair's load
    double secant_H = 0.0;         // the Lq the pair's fit used
    double incremental_H = 0.0;
    double secant_mean_V_H = 0.0;  // S_sec and S_inc over the matched samples
    double incremental_mean_V_H = 0.0;
    double secant_x_sum_A_V_H = 0.0;  // weighted by dId, with dId's sum of squares
    double incremental_x_sum_A_V_H = 0.0;
    double emf_d_Wb = 0.0;            // the angle error's EMF share the fit used, and its terms
    double emf_mean_V_Wb = 0.0;
    double emf_x_sum_A_V_Wb = 0.0;
    double x_sq_sum_A2 = 0.0;
  };
  [[nodiscard]] LqTerm lq_term(const PairConditions& c) const;
  [[nodiscard]] double lq_secant_at(const LqShape::At& shape) const;  // the learned curve there
  [[nodiscard]] double lq_incremental_at(const LqShape::At& shape) const;
  // The learned curve now less the one a pair used: (secant, incremental, EMF share), 0 with
  // learning off.
  [[nodiscard]] std::array<double, 3> lq_change_H(const LqTerm& t) const;
  // How an estimate moves with the curve's state (a, b, c, b2), summed over the pairs it is made
  // of: add(dR/dLq_sec, dR/dLq_inc, dR/dc, u) for each.
  struct LqGradient {
    std::array<double, kLqStates> g{};  // (a, b, c, b2), as lq_p_
    void add(double d_secant, double d_incremental, double d_emf, const LqShape::At& shape);
  };
  // The variance the learned curve's uncertainty leaves in such an estimate.
  [[nodiscard]] double lq_variance(const LqGradient& g) const;
  double level_for(int recording) const;       // injection level of recording 1 or 2 (in units of F)
  Dq injection_current(const SchedulerInput& in) const;
  double edge_value(double elapsed_s) const;   // 0..1 along a rising window edge
  double delta_theta(double needed_rad, double omega_e_rad_s) const;

  InjectionConfig config_;
  double period_s_;
  PairRecorder recorder_;

  SchedulerPhase phase_ = SchedulerPhase::kIdle;
  SchedulerOutput out_;  // what step() returns (see there)
  double next_event_s_ = 0.0;
  double retry_after_s_ = 0.0;      // a request waits until then after an event that yielded nothing
  bool last_event_refused_ = false;  // no pairs since the last event that yielded some (refusal_jitter)
  std::uint64_t retry_rng_ = 0;    // refusal_jitter's generator state (splitmix64, fixed seed)
  // After an angle-based pair lost its speed (the rotor stopped under it), the event is tried
  // again once the shaft has rested a time-based recording's length (record_time_s), not only
  // after retry_s: a press that dwells 0.7 s between its strokes had every retry fall in the
  // next stroke, and was never measured. -1: not at rest.
  bool retry_at_rest_ = false;
  double rest_since_s_ = -1.0;
  double rest_iq_A_ = 0.0;         // the motoring iq when the rest began
  double motoring_limit_A_ = std::numeric_limits<double>::infinity();  // set_motoring_current_limit
  int level_index_ = 0;             // next level of the event in progress
  bool in_event_ = false;
  bool held_ = false;               // hold_events()
  BlockedSums event_sums_{};        // accepted pairs of the event, summed
  std::array<BlockedSums, InjectionConfig::kMaxLevels> event_pair_sums_{};  // and one by one
  // Their means, one computed per control period once the pairs are done (finish_event).
  std::array<std::optional<PairMeans>, InjectionConfig::kMaxLevels> event_means_{};
  int event_means_done_ = 0;
  int event_pairs_ = 0;
  double event_min_f_A_ = 0.0;      // smallest F among the event's accepted pairs
  double event_max_iq_A_ = 0.0;     // largest motoring |iq| among them
  double event_max_speed_ = 0.0;    // largest electrical speed among them
  double event_time_weight_ = 0.0;  // sum of their weights (1 / var Rs)
  double event_time_sum_s_ = 0.0;   // sum of weight * (pair's Rs time - event_start_s_)
  double event_time_plain_sum_s_ = 0.0;  // sum of (pair's Rs time - event_start_s_), unweighted
  // The same sums of its recordings' times relative to its Rs time (t1 - t, t2 - t): weighted
  // [0] and [1], unweighted [2] and [3] (EventEstimate::measured_from_s).
  std::array<double, 4> event_span_sums_s_{};
  double event_start_s_ = 0.0;
  std::array<double, InjectionConfig::kMaxLevels> event_pair_time_s_{};  // each pair's Rs time (PairConditions::rs_time_s)
  std::array<LqTerm, InjectionConfig::kMaxLevels> event_pair_lq_{};  // each pair's Lq term (lq_term)
  LqTerm pair_lq_{};                // the Lq the pair in progress is fitted with (u, secant, incremental)
  std::array<PairConditions, InjectionConfig::kMaxLevels> event_q_{};
  int event_q_pairs_ = 0;
  std::uint32_t learned_version_ = 0;  // learned_version()
  double vx_V_ = 0.0;               // inverter voltage prior
  double vx_var_ = 0.0;
  double vx_slope_ = 0.0;           // vx_bus_slope()
  double vx_slope_var_ = 0.0;
  double vx_cov_ = 0.0;             // covariance of Vx and the slope
  bool vx_learned_ = false;         // VxState::learned
  double learned_bus_offset_V_ = 0.0;  // last_learned_bus_offset_V()
  double event_bus_sum_V_ = 0.0;    // the event's bus offsets (SchedulerInput::bus_offset_V), summed
  std::uint32_t event_bus_periods_ = 0;
  // The pair in progress's bus offsets over each recording, summed, and each accepted pair's
  // recordings' mean bus offsets (EventEstimate::bus_spread_V).
  std::array<double, 2> pair_bus_sum_V_{};
  std::array<std::uint32_t, 2> pair_bus_periods_{};
  std::array<std::array<double, 2>, InjectionConfig::kMaxLevels> event_pair_bus_V_{};
  double event_bus_error_ohm_ = 0.0;  // the largest bus_change_error_ohm of the event's accepted pairs
  [[nodiscard]] double event_bus_offset_V() const {
    return event_bus_periods_ > 0 ? event_bus_sum_V_ / static_cast<double>(event_bus_periods_) : 0.0;
  }
  // Recording k's (0, 1) mean bus offset in the pair in progress; the event's so far where it
  // counted no period.
  [[nodiscard]] double recording_bus_offset_V(std::size_t k) const {
    return pair_bus_periods_[k] > 0 ? pair_bus_sum_V_[k] / static_cast<double>(pair_bus_periods_[k]) : event_bus_offset_V();
  }
  // set_motoring_voltage(): NaN time until given.
  double motoring_voltage_time_s_ = std::numeric_limits<double>::quiet_NaN();
  double winding_rs_ohm_ = std::numeric_limits<double>::quiet_NaN();  // set_winding_resistance
  double winding_rs_var_ohm2_ = 0.0;
  Dq motoring_voltage_V_{};
  double motoring_voltage_mean_sq_V2_ = 0.0;
  double lq_H_ = 0.0;               // learned q-axis inductance (see InjectionConfig::learn_lq)
  LqShape lq_shape_;                // the saturation curve's shape and its commissioned b0 (InjectionConfig::lq_map)
  bool lq_resolved_ = false;        // saturation_variance_resolved(), kept as b's variance changes
  double lq_b_H_ = 0.0;             // its saturation: secant lost where s = 1 (LqShape)
  double lq_b2_H_ = 0.0;            // its bend: a further b2 s^2 lost (learn_lq)
  bool lq_bend_active_ = false;     // b2 learned: three anchors (add_bend_prior)
  // The loads that have taught the curve (their s), at least a lever of 2 kLqUnmodelledFraction
  // / lq_saturation_std_fraction apart: a pair within a lever of one is taken at its s
  // (learn_lq). kLqUnmodelledFraction: the share of a pair's Lq that the model does not hold and
  // that pairs at one operating point share (measured on unseen round 17's spindle: 0.57 %
  // between an event's two levels, 0.3 % between 11000 and 12000 rpm). With the default lever
  // (0.05) and s capped at 1.44, at most 29 anchors fit; past kMaxLqAnchors (a prior fraction
  // above about 0.21) a pair is taken at the nearest.
  static constexpr double kLqUnmodelledFraction = 0.005;
  static constexpr int kMaxLqAnchors = 32;
  std::array<double, kMaxLqAnchors> lq_anchors_{};
  int lq_anchor_count_ = 0;
  // A listening pair: two recordings with no pulse, under a load where the torque budget refuses
  // every pulse and no anchor lies within a lever (listens()); it teaches the curve only.
  bool listening_ = false;
  bool event_listened_ = false;  // (one per event)
  std::uint32_t listening_pairs_ = 0;
  std::uint32_t listening_learned_ = 0;
  double emf_d_Wb_ = 0.0;           // the angle error's EMF share c (InjectionConfig::lq_angle_std_rad)
  double bridge_band_A_ = 0.0;      // set_bridge_band
  LqCovariance lq_p_{};  // covariance of (a, b, c, b2): lq_H_, lq_b_H_, emf_d_Wb_, lq_b2_H_
  bool time_based_ = false;
  double direction_ = 1.0;
  double f_A_ = 0.0;                // magnitude for this pair
  double level1_ = 1.0;             // levels of recordings 1 and 2 for this pair (units of F)
  double level2_ = -1.0;
  bool field_weakening_ = false;    // this pair is a field-weakening pair (budget())
  double fw_low_level_ = 0.0;       // its lower level (units of F), from the budget
  bool event_field_weakening_ = false;  // the event has an accepted field-weakening pair
  double phase_start_s_ = 0.0;
  double level_from_ = 0.0;         // ramp start level (units of F)
  double level_to_ = 0.0;           // ramp end level
  int ramp_count_ = 0;              // ramps done in this pair (to sequence down/up)
  int recording_ = 0;               // 1 or 2 while recording, else 0
  double origin2_ = 0.0;            // matching coordinate where recording 2 starts
  double pulse_start_theta_ = 0.0;  // fixed-angle: unwrapped angle where the pulse starts
  double pulse_arc_rad_ = 0.0;      // fixed-angle: total arc of the pulse (2 theta_w + theta_i)
  double window_arc_rad_ = 0.0;
  double record_arc_rad_ = 0.0;     // angle-based recording length of this pair
  double theta_f_unwrapped_ = 0.0;  // fixed-angle: the centre of the current pulse
  double dc_theta_f_rad_ = 0.0;     // DC: stator angle of the vector for this pair
  std::size_t recorder_capacity_;
};

}  // namespace pmsm::core
