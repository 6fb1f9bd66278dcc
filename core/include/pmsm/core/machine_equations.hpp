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

// Eq. 10, Tem = Kt * iqr, extended with the reluctance torque of a salient machine:
// Tem = 3/2 * p * (psi_m * iq + (Ld - Lq) * id * iq). With Ld = Lq it reduces to Eq. 10.
[[nodiscard]] double electromagnetic_torque_Nm(double flux_linkage_Wb, double ld_H, double lq_H,
                                               int pole_pairs, const Dq& i_A);

// Eq. 1: Rs = Rs0 + alpha * Rs0 * (Ts - T0), copper alpha = 3.93e-3 per degree C.
inline constexpr double kCopperAlpha_per_C = 3.93e-3;

[[nodiscard]] constexpr double resistance_at_temperature_ohm(double rs0_ohm, double t0_C,
                                                             double temp_C,
                                                             double alpha_per_C = kCopperAlpha_per_C) {
  return rs0_ohm + alpha_per_C * rs0_ohm * (temp_C - t0_C);
}

// Eq. 1 solved for the winding temperature.
[[nodiscard]] constexpr double temperature_from_resistance_C(double rs_ohm, double rs0_ohm,
                                                             double t0_C,
                                                             double alpha_per_C = kCopperAlpha_per_C) {
  return t0_C + (rs_ohm / rs0_ohm - 1.0) / alpha_per_C;
}

// Temperature change per resistance change, d(Ts)/d(Rs) = 1 / (alpha * Rs0) (from Eq. 1).
[[nodiscard]] constexpr double temperature_per_resistance_C_per_ohm(
    double rs0_ohm, double alpha_per_C = kCopperAlpha_per_C) {
  return 1.0 / (alpha_per_C * rs0_ohm);
}

}  // namespace pmsm::core
