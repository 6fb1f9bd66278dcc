#include "pmsm/core/baseline_estimator.hpp"

#include <cmath>

namespace pmsm::core {

BaselineEstimator::BaselineEstimator(const BaselineConfig& config)
    : config_(config),
      lambda_(1.0 - 1.0 / std::max(1.0, config.memory_s / (config.period_s * config.decimation))) {
  theta_ << config.initial_rs_ohm, config.initial_ke_V_s_per_rad, 0.0;
  p_ = Eigen::Matrix3d::Zero();
  p_(0, 0) = 1e-2;
  p_(1, 1) = 1e-2;
  p_(2, 2) = config.fit_dead_time ? 10.0 : 0.0;
}

double BaselineEstimator::rs_std_ohm() const { return std::sqrt(std::max(p_(0, 0) * residual_var_, 0.0)); }

void BaselineEstimator::add(const PeriodSample& s) {
  // The gate on the speed observer's speed: the period's own (s.omega_e_rad_s, from the
  // encoder's advance) steps by a count per period, 11.5 rad/s on the reference, and near the
  // threshold would open and close it sample by sample.
  if (std::abs(s.omega_m_rad_s) * config_.pole_pairs < config_.min_speed_rad_s || s.voltage_limited) {
    count_ = 0;
    y_ = 0.0;
    phi_.setZero();
    return;
  }
  y_ += s.v_V.q - s.omega_e_rad_s * config_.ld_H * s.i_A.d;
  phi_ += Eigen::Vector3d(s.i_A.q, s.omega_m_rad_s, config_.fit_dead_time ? s.dead_time_pattern.q : 0.0);
  if (++count_ < config_.decimation) {
    return;
  }
  const double y = y_ / count_;
  const Eigen::Vector3d phi = phi_ / count_;
  count_ = 0;
  y_ = 0.0;
  phi_.setZero();

  const double error = y - phi.dot(theta_);
  const Eigen::Vector3d pphi = p_ * phi;
  const double denominator = lambda_ + phi.dot(pphi);
  const Eigen::Vector3d k = pphi / denominator;
  theta_ += k * error;
  p_ = (p_ - k * pphi.transpose()) / lambda_;
  p_ = 0.5 * (p_ + p_.transpose());
  residual_var_ = lambda_ * residual_var_ + (1.0 - lambda_) * error * error;
  ++updates_;
}

}  // namespace pmsm::core
