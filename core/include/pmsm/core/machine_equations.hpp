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

// Temperature change per resistance change, d(Ts)/d(Rs) = (K + T0) / Rs0 = 1 / (alpha(T0) Rs0).
[[nodiscard]] constexpr double temperature_per_resistance_C_per_ohm(double rs0_ohm, double t0_C,
                                                                    double inferred_zero_C = kCopperInferredZero_C) {
  return (inferred_zero_C + t0_C) / rs0_ohm;
}

}  // namespace pmsm::core
