// Motor parameters: Table I of the paper, as a plain struct with the unit in every name.
//
// Conventions (docs/parameters.md explains each reading of Table I):
// - Resistances and inductances are per phase, phase-to-neutral (star equivalent).
// - Currents in the dq frame are amplitude-invariant (Eq. 2), i.e. phase peak amperes.
// - Table I's Ke and Kt are given in RMS line quantities; the dq model (Eq. 3) needs the
//   phase-peak forms, which the free functions below derive.
#pragma once

#include <array>
#include <cmath>

namespace pmsm::core {

// A q-axis flux map as the estimator takes it: the secant inductance psi_q / iq at up to
// kMaxPoints q-axis currents (peak A, ascending, > 0). The no-load value is motor.lq_H.
struct LqMap {
  static constexpr int kMaxPoints = 8;
  std::array<double, kMaxPoints> current_A{};
  std::array<double, kMaxPoints> secant_H{};
  int points = 0;
};

struct MotorParams {
  double kt_Nm_per_A_rms = 2.08;          // Table I torque constant, per RMS phase ampere
  double ke_V_s_per_rad = 1.19;           // Table I EMF constant: line-to-line RMS volts per mechanical rad/s
  double rated_speed_rad_s = 314.0;       // mechanical
  double rated_power_W = 11.9e3;
  double continuous_current_A_rms = 31.9;
  double stall_current_A_rms = 117.5;
  double max_phase_voltage_V = 480.0;
  double rs_ohm = 0.133;                  // phase-to-neutral stator resistance at rs_reference_temp_C
  double rs_reference_temp_C = 25.0;
  double inductance_line_to_line_H = 11e-3;
  double ld_H = 5.5e-3;                   // d-axis synchronous inductance (L_ll / 2 for a round rotor)
  double lq_H = 5.5e-3;                   // q-axis synchronous inductance
  // The secant q-axis inductance psi_q / iq at the rated current (continuous, peak), from the
  // motor's flux map or datasheet; 0: not known. A saturating machine's Lq falls with load.
  double lq_rated_H = 0.0;
  // Or the flux map itself: its secant Lq at several q-axis currents (LqMap; lq_H is its no-load
  // value). At most one of the two is given.
  LqMap lq_map{};
  double inertia_kg_m2 = 0.00841;
  int pole_pairs = 3;
  double thermal_time_constant_s = 2880.0;
  double coulomb_friction_Nm = 0.908;
};

// sqrt(2/3): from line-to-line RMS to phase peak.
inline constexpr double kLineRmsToPhasePeak = 0.81649658092772603;
inline constexpr double kSqrt2 = 1.41421356237309505;

// The Ke of Eq. 3 (vqr = ... + Ke * wm): phase-peak volts per mechanical rad/s.
[[nodiscard]] constexpr double emf_constant_dq_V_s_per_rad(const MotorParams& m) {
  return m.ke_V_s_per_rad * kLineRmsToPhasePeak;
}

// Permanent-magnet flux linkage psi_m (phase-peak volts per electrical rad/s).
[[nodiscard]] constexpr double flux_linkage_Wb(const MotorParams& m) {
  return emf_constant_dq_V_s_per_rad(m) / m.pole_pairs;
}

// The Kt of Eq. 10 (Tem = Kt * iqr) for amplitude-invariant iqr, derived from power balance
// (3/2 * p * psi_m). Table I's Kt (per RMS ampere) divided by sqrt(2) agrees within 1 %.
[[nodiscard]] constexpr double torque_constant_dq_Nm_per_A(const MotorParams& m) {
  return 1.5 * m.pole_pairs * flux_linkage_Wb(m);
}

[[nodiscard]] inline double rms_to_peak(double rms) { return rms * kSqrt2; }

// Peak phase current (the dq-vector limit) for the continuous and the stall rating.
[[nodiscard]] inline double continuous_current_peak_A(const MotorParams& m) {
  return rms_to_peak(m.continuous_current_A_rms);
}
[[nodiscard]] inline double stall_current_peak_A(const MotorParams& m) {
  return rms_to_peak(m.stall_current_A_rms);
}

// Defaults that scale with the configured motor: Table I's absolute numbers written as
// fractions of its resistance and of its rated current (the continuous current, peak), so
// that another motor gets sensible values (the Table I window 0.09-0.27 ohm never lets a
// 1.6 ohm servo calibrate). Each fraction is the Table I number over the Table I quantity,
// so the Table I motor gets exactly the old numbers ((a / b) * b == a for these operands in
// IEEE double; a unit test checks it).
struct MotorRelativeDefaults {
  double rs_min_ohm;         // resistance plausibility window: 0.09 / 0.133 = 0.677 Rs (about -57 C)
  double rs_max_ohm;         // 0.27 / 0.133 = 2.03 Rs (about 287 C)
  double max_load_change_A;  // load-change guard: 1.5 A / 45.1 A = 0.0332 I_rated
  double injection_f_A;      // injection magnitude F: 35 A / 45.1 A = 0.776 I_rated
  double injection_f_min_A;  // smallest F worth a pair: 5 A / 45.1 A = 0.111 I_rated
  double calibration_f_A;    // calibration magnitude at no load: 50 A / 45.1 A = 1.11 I_rated
  // Speed-change guard (electrical rad/s): 3 rad/s at Table I's Rs / Lq = 24.2 /s, in
  // proportion to the motor's Rs / Lq. The d-axis fit carries the speed through Lq d(w iq)
  // (Eq. 37); what a speed change can bias is an error of that Lq times iq times the change,
  // against the pair's resistive signal Rs dId. With iq and F both in proportion to the rated
  // current, the change a given relative error allows goes as Rs / Lq: a 1.6 ohm, 6.8 mH servo
  // allows ten times Table I's (29 rad/s), where 3 rad/s rejected the pairs whose speed moved
  // with the injection's own reluctance torque, a change the fit models.
  double max_speed_change_rad_s;
};

inline constexpr double kTableIRs_ohm = 0.133;
inline constexpr double kTableILq_H = 5.5e-3;
inline constexpr double kTableIRatedCurrent_A = 31.9 * kSqrt2;  // Icont, peak

[[nodiscard]] constexpr MotorRelativeDefaults motor_relative_defaults(const MotorParams& m) {
  const double rs = m.rs_ohm;
  const double rated_A = m.continuous_current_A_rms * kSqrt2;
  return {
      .rs_min_ohm = 0.09 / kTableIRs_ohm * rs,
      .rs_max_ohm = 0.27 / kTableIRs_ohm * rs,
      .max_load_change_A = 1.5 / kTableIRatedCurrent_A * rated_A,
      .injection_f_A = 35.0 / kTableIRatedCurrent_A * rated_A,
      .injection_f_min_A = 5.0 / kTableIRatedCurrent_A * rated_A,
      .calibration_f_A = 50.0 / kTableIRatedCurrent_A * rated_A,
      // (x / x == 1 exactly: the Table I motor gets exactly 3.)
      .max_speed_change_rad_s = 3.0 * ((rs / m.lq_H) / (kTableIRs_ohm / kTableILq_H)),
  };
}

}  // namespace pmsm::core
