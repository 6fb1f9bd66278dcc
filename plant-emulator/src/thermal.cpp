#include "pmsm/plant/thermal.hpp"

#include "pmsm/shaft_fan.hpp"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

#include <Eigen/Dense>
#include <unsupported/Eigen/MatrixFunctions>

namespace pmsm::plant {

static_assert(ThermalNetwork::kFanSpeedSpan == math::kFanSpeedSpan, "the plant's fan span is the shared formula's");

ThermalNetwork::ThermalNetwork(const ThermalConfig& config, double step_s) : step_s_(step_s) {
  const double g_wh = 1.0 / config.winding_to_housing_K_W;
  const double g_ha = 1.0 / config.housing_to_ambient_K_W;
  const double g_rh = 1.0 / config.rotor_to_housing_K_W;
  const double g_ra = 1.0 / config.rotor_to_ambient_K_W;

  Eigen::Matrix3d g = Eigen::Matrix3d::Zero();
  g(kWinding, kWinding) = g_wh;
  g(kWinding, kHousing) = -g_wh;
  g(kHousing, kWinding) = -g_wh;
  g(kHousing, kHousing) = g_wh + g_rh + g_ha;
  g(kHousing, kRotor) = -g_rh;
  g(kRotor, kHousing) = -g_rh;
  g(kRotor, kRotor) = g_rh + g_ra;
  const Eigen::Vector3d g_amb(0.0, g_ha, g_ra);
  const Eigen::Vector3d c(config.winding_capacity_J_K, config.housing_capacity_J_K, config.rotor_capacity_J_K);
  const Eigen::Matrix3d c_inv = c.cwiseInverse().asDiagonal();

  // Augmented system [T; u]' = [A B; 0 0]·[T; u] with u = (P_w, P_h, P_r, T_amb) held
  // constant over a step: exp of the augmented matrix gives exp(A·h) and the input matrix
  // of the exact zero-order-hold discretisation in one go.
  Eigen::Matrix<double, 7, 7> m = Eigen::Matrix<double, 7, 7>::Zero();
  m.block<3, 3>(0, 0) = -c_inv * g;
  m.block<3, 3>(0, 3) = c_inv;
  m.block<3, 1>(0, 6) = c_inv * g_amb;
  const Eigen::Matrix<double, 7, 7> e = (m * step_s).exp();

  const Eigen::Vector3d c_inv_sqrt = c.cwiseSqrt().cwiseInverse();
  const Eigen::Matrix3d c_g_c = c_inv_sqrt.asDiagonal() * g * c_inv_sqrt.asDiagonal();
  for (int i = 0; i < kNodes; ++i) {
    for (int j = 0; j < kNodes; ++j) {
      a_d_[static_cast<std::size_t>(i)][static_cast<std::size_t>(j)] = e(i, j);
      c_g_c_[static_cast<std::size_t>(i)][static_cast<std::size_t>(j)] = c_g_c(i, j);
    }
    for (int j = 0; j < kNodes + 1; ++j) {
      b_d_[static_cast<std::size_t>(i)][static_cast<std::size_t>(j)] = e(i, 3 + j);
    }
  }
  const double t0 = config.initial_C.value_or(config.ambient_C);
  temps_C_ = {t0, t0, t0};
  if (config.fan_speed_rad_s > 0.0) {
    // The shaft fan's part of the housing's path enters a step as a heat flow at the step's start
    // temperature (Plant): accurate and monotone while a step is a small part of the housing's
    // own time constant through its path at the largest share; at 1e6 x and 1 kHz on the plant's
    // defaults a share of 3 would oscillate and one of 5 diverge.
    const double largest = fan_share(config, kFanSpeedSpan * config.fan_speed_rad_s);
    const double tau_s = config.housing_to_ambient_K_W * config.housing_capacity_J_K / largest;
    if (!(step_s <= kMaxFanStepFraction * tau_s)) {
      throw ConfigError(fmt::format(
          "thermal.fan_speed_rad_s: with a shaft fan a thermal step ({} s: thermal.acceleration over the PWM "
          "frequency) must be at most {} of the housing's time constant through its path at the fan's largest share "
          "(thermal.housing_capacity_J_K x thermal.housing_to_ambient_K_W / {}, {} s); lower the acceleration",
          common::format_number(step_s), common::format_number(kMaxFanStepFraction), common::format_number(largest),
          common::format_number(tau_s)));
    }
  }
}

void ThermalNetwork::step(const Vector& loss_W, double ambient_C) {
  Vector next{};
  for (std::size_t i = 0; i < kNodes; ++i) {
    double acc = 0.0;
    for (std::size_t j = 0; j < kNodes; ++j) {
      acc += a_d_[i][j] * temps_C_[j] + b_d_[i][j] * loss_W[j];
    }
    acc += b_d_[i][kNodes] * ambient_C;
    next[i] = acc;
  }
  temps_C_ = next;
}

double ThermalNetwork::fan_share(const ThermalConfig& config, double omega_m_rad_s) {
  return math::shaft_fan_share(omega_m_rad_s, config.fan_speed_rad_s, config.fan_standstill_share,
                               config.fan_exponent);
}

double ThermalNetwork::dominant_time_constant_s() const {
  Eigen::Matrix3d a;
  for (int i = 0; i < kNodes; ++i) {
    for (int j = 0; j < kNodes; ++j) {
      a(i, j) = c_g_c_[static_cast<std::size_t>(i)][static_cast<std::size_t>(j)];
    }
  }
  // C^-1·G is similar to the symmetric positive-definite C^-1/2·G·C^-1/2: its eigenvalues are
  // real and positive, here in closed form (ascending); the smallest one is the slowest mode.
  // (The general eigensolver gave the same, at several times this file's compile time.)
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver;
  solver.computeDirect(a, Eigen::EigenvaluesOnly);
  return 1.0 / solver.eigenvalues()(0);
}

}  // namespace pmsm::plant
