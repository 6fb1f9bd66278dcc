// The machine equations the paper builds on: the rotor-frame voltage model (Eq. 3), torque
// (Eq. 10, plus the reluctance term that saliency adds) and resistance vs temperature (Eq. 1).
#pragma once

#include "pmsm/core/transforms.hpp"

namespace pmsm::core {

struct DqMachine {
  double rs_ohm = 0.0;
  double ld_H = 0.0;
  double lq_H = 0.0;
  double ke_V_s_per_rad = 0.0;  // Eq. 3's Ke: phase-peak volts per mechanical rad/s
};

// Eq. 3: rotor-frame stator voltages for currents i, their time derivatives di_dt, electrical
// speed omega_e and mechanical speed omega_m.
[[nodiscard]] Dq rotor_frame_voltage(const DqMachine& m, const Dq& i_A, const Dq& di_dt_A_s,
                                     double omega_e_rad_s, double omega_m_rad_s);

// One PWM period as the estimator sees it (docs/estimator.md §1, "One period, averaged"). The
// bridge holds its voltage vector fixed in the stator for the whole period, while the rotor
// frame turns by a = w T. In the rotor frame the vector therefore turns back: with u in
// [-1/2, 1/2] across the period, vd(u) = vd + a u vq and vq(u) = vq - a u vd (to first order).
// Two consequences for a period's averages:
//  - the mean rotor-frame voltage is the command shrunk by sin(a/2) / (a/2) = 1 - a^2 / 24. The
//    bridge's error is stator-fixed too, except that a phase's sign flips where its current
//    crosses zero inside the period, so its mean is the mid-angle pattern shrunk the same way
//    plus a (m_q, -m_d), m the pattern's first moment (soft_sign_moment, projected like the
//    pattern): period_sign_pattern;
//  - the current is not linear in time, so the mean of its two end samples is not its mean.
//    For a driving voltage w(u) on an inductance L the mean lies (T / L) M1 below the ends'
//    mean, M1 being w's first moment, the integral of u w(u) du: a vq / 12 on the d axis and
//    -a vd / 12 on the q axis from the turning command, -Vx m from the bridge, and from the
//    machine's own terms, which move with the current across the period (dI its change over
//    the period), (w Lq dIq - Rs dId) / 12 on d and (-w Ld dId - Rs dIq) / 12 on q:
//    period_mean_current.
// In a pair the ends' mean differs between the levels by w Ld dId / 12 through vq, and the q
// part is multiplied by w Lq in the d-axis fit: at the reference's rated speed a
// field-weakening pair read 0.6 % low at 10 kHz and 1.75 % at 5 kHz (docs/accuracy.md).
[[nodiscard]] constexpr double period_voltage_shrink(double rotation_rad) {
  return 1.0 - rotation_rad * rotation_rad / 24.0;
}
// mean: the sign pattern at the period's middle angle (mean soft sign per phase, projected);
// moment: the same projection of the signs' first moments.
[[nodiscard]] constexpr Dq period_sign_pattern(const Dq& mean, const Dq& moment, double rotation_rad) {
  const double shrink = period_voltage_shrink(rotation_rad);
  return {shrink * mean.d + rotation_rad * moment.q, shrink * mean.q - rotation_rad * moment.d};
}
struct PeriodMachine {
  double rs_ohm = 0.0;
  double ld_H = 0.0;
  double lq_H = 0.0;
};
// ends_mean_A: the mean of the period's two current samples; change_A: the second minus the
// first; v_machine_V: the mean voltage that reached the machine (the command less the
// bridge's Vx G); sign_moment: the sign pattern's first moment in the rotor frame (per volt of
// per-phase error).
[[nodiscard]] constexpr Dq period_mean_current(const Dq& ends_mean_A, const Dq& change_A, const Dq& v_machine_V,
                                               const Dq& sign_moment, double vx_V, double rotation_rad,
                                               double period_s, const PeriodMachine& m) {
  const double w = rotation_rad / period_s;
  const double m1_d = (rotation_rad * v_machine_V.q + w * m.lq_H * change_A.q - m.rs_ohm * change_A.d) / 12.0 -
                      vx_V * sign_moment.d;
  const double m1_q = (-rotation_rad * v_machine_V.d - w * m.ld_H * change_A.d - m.rs_ohm * change_A.q) / 12.0 -
                      vx_V * sign_moment.q;
  return {ends_mean_A.d - period_s * m1_d / m.ld_H, ends_mean_A.q - period_s * m1_q / m.lq_H};
}

// Eq. 10, Tem = Kt * iqr, extended with the reluctance torque of a salient machine:
// Tem = 3/2 * p * (psi_m * iq + (Ld - Lq) * id * iq). With Ld = Lq it reduces to Eq. 10.
// Inline: the control step reports it every period.
[[nodiscard]] inline double electromagnetic_torque_Nm(double flux_linkage_Wb, double ld_H, double lq_H,
                                                      int pole_pairs, const Dq& i_A) {
  return 1.5 * pole_pairs * (flux_linkage_Wb * i_A.q + (ld_H - lq_H) * i_A.d * i_A.q);
}

// Eq. 1, Rs = Rs0 + alpha Rs0 (Ts - T0), with alpha referred to T0. A conductor's resistance
// is proportional to (K + T), K its inferred zero-resistance temperature, so
//   alpha(T0) = 1 / (K + T0)   and   Rs(T) / Rs(T0) = (K + T) / (K + T0).
// Annealed copper: K = 234.5 C (IEEE Std 118, IEC 60034-1's 235), i.e. the paper's
// alpha = 3.93e-3 /C at 20 C, 3.85e-3 at 25 C, 4.0e-3 at 15 C. Aluminium: K = 225 C
// (IEC 60034-1). Applying one alpha at every T0 is wrong by several degrees once the
// calibration's T0 is away from alpha's own reference (-10 C or +45 C).
inline constexpr double kCopperInferredZero_C = 234.5;
inline constexpr double kAluminiumInferredZero_C = 225.0;

[[nodiscard]] constexpr double alpha_at_C(double t0_C, double inferred_zero_C = kCopperInferredZero_C) {
  return 1.0 / (inferred_zero_C + t0_C);
}

[[nodiscard]] constexpr double resistance_at_temperature_ohm(double rs0_ohm, double t0_C, double temp_C,
                                                             double inferred_zero_C = kCopperInferredZero_C) {
  return rs0_ohm * (inferred_zero_C + temp_C) / (inferred_zero_C + t0_C);  // Eq. 1
}

// Eq. 1 solved for the winding temperature.
[[nodiscard]] constexpr double temperature_from_resistance_C(double rs_ohm, double rs0_ohm, double t0_C,
                                                             double inferred_zero_C = kCopperInferredZero_C) {
  return rs_ohm / rs0_ohm * (inferred_zero_C + t0_C) - inferred_zero_C;
}

// A motor cable's resistance (copper) at temp_C from its value at 20 C (the data sheets').
[[nodiscard]] constexpr double cable_resistance_at_C(double cable_20C_ohm, double temp_C) {
  return resistance_at_temperature_ohm(cable_20C_ohm, 20.0, temp_C, kCopperInferredZero_C);
}

// A resistance measured with the winding at winding_C and a cable of cable_now_ohm (at the
// ambient), referred to the winding and the cable both at t0_C (a calibration's Rs0): Eq. 1 on
// the winding's share alone.
[[nodiscard]] constexpr double resistance_referred_to_C(double rs_ohm, double winding_C, double t0_C,
                                                        double cable_now_ohm, double cable_at_t0_ohm,
                                                        double inferred_zero_C = kCopperInferredZero_C) {
  return (rs_ohm - cable_now_ohm) * resistance_at_temperature_ohm(1.0, winding_C, t0_C, inferred_zero_C) +
         cable_at_t0_ohm;
}

// Temperature change per resistance change, d(Ts)/d(Rs) = (K + T0) / Rs0 = 1 / (alpha(T0) Rs0).
[[nodiscard]] constexpr double temperature_per_resistance_C_per_ohm(double rs0_ohm, double t0_C,
                                                                    double inferred_zero_C = kCopperInferredZero_C) {
  return (inferred_zero_C + t0_C) / rs0_ohm;
}

}  // namespace pmsm::core
