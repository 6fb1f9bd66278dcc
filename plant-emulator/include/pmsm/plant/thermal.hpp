// Lumped thermal network: winding, stator iron/housing and rotor (magnet) nodes, with the
// ambient as a boundary temperature.
//
//   C·dT/dt = -G·T + g_amb·T_amb + P
//
// C = diag(C_winding, C_housing, C_rotor); G is the conductance (Laplacian-like) matrix of
// the links winding-housing, rotor-housing, housing-ambient and rotor-ambient; P holds the
// losses fed into each node. The network is advanced by its exact discretisation for a
// zero-order-hold loss input (matrix exponential), so any step length is exact.
#pragma once

#include <array>

#include "pmsm/plant/config.hpp"

namespace pmsm::plant {

class ThermalNetwork {
 public:
  enum Node : int { kWinding = 0, kHousing = 1, kRotor = 2 };
  static constexpr int kNodes = 3;
  using Vector = std::array<double, kNodes>;
  using Matrix = std::array<std::array<double, kNodes>, kNodes>;

  // Prepares the exact discretisation for steps of step_s of thermal time (the caller
  // multiplies by the acceleration factor). Throws ConfigError where a shaft fan's step would be
  // too long (kMaxFanStepFraction).
  ThermalNetwork(const ThermalConfig& config, double step_s);

  // Advances by one step with losses loss_W (held constant over the step) and ambient_C.
  void step(const Vector& loss_W, double ambient_C);

  void set_temperatures_C(const Vector& temps_C) { temps_C_ = temps_C; }
  [[nodiscard]] const Vector& temperatures_C() const { return temps_C_; }
  [[nodiscard]] double step_s() const { return step_s_; }

  // The housing's path to the ambient at the mechanical speed omega_m_rad_s, as a share of
  // 1 / housing_to_ambient_K_W: 1 without a shaft fan (thermal.fan_speed_rad_s 0), else
  // standstill_share + (1 - standstill_share) (|w| / fan_speed)^exponent, |w| held at
  // kFanSpeedSpan times the fan's speed beyond it (common/math/pmsm/shaft_fan.hpp, the drive's
  // formula too).
  static constexpr double kFanSpeedSpan = 2.0;
  // With a fan, a step at most this share of the housing's time constant at the largest share
  // (the constructor throws ConfigError beyond).
  static constexpr double kMaxFanStepFraction = 0.05;
  [[nodiscard]] static double fan_share(const ThermalConfig& config, double omega_m_rad_s);

  // Slowest time constant of the network (-1/largest eigenvalue of -C^-1·G), in thermal
  // seconds, with the housing's path at housing_to_ambient_K_W. For diagnostics and documentation.
  [[nodiscard]] double dominant_time_constant_s() const;

 private:
  Matrix a_d_{};                      // exp(A·h)
  std::array<std::array<double, kNodes + 1>, kNodes> b_d_{};  // ∫exp(A·s)ds·B, inputs P and T_amb
  Matrix c_g_c_{};                    // C^-1/2·G·C^-1/2 (similar to C^-1·G, symmetric), for the time constant
  Vector temps_C_{};
  double step_s_ = 0.0;
};

}  // namespace pmsm::plant
