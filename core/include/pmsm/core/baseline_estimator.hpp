// The no-injection baseline: the stator resistance from the voltage equation during normal
// operation, without any injected current. Recursive least squares on the q-axis of Eq. 3,
//
//   vq - w Ld id  =  Rs iq + Ke wm + Vx Gq
//
// over whatever excitation the load provides (Rs needs iq to vary independently of the
// speed). This is the approach the paper's introduction calls insufficient for high-power
// machines, where Rs iq is about 1 % of the terminal voltage; it is here to be measured
// against, with the same dead-time term the injection methods get.
#pragma once

#include <Eigen/Core>

#include "pmsm/core/pair_estimator.hpp"

namespace pmsm::core {

struct BaselineConfig {
  double period_s = 1e-4;
  double memory_s = 2.0;        // RLS forgetting horizon (controller seconds)
  int decimation = 10;          // periods averaged into one RLS sample
  double ld_H = 5.5e-3;
  bool fit_dead_time = true;
  double min_speed_rad_s = 30.0;  // electrical
  int pole_pairs = 3;             // the speed gate reads the speed observer's mechanical speed
  double initial_rs_ohm = 0.133;
  double initial_ke_V_s_per_rad = 0.9716;
};

class BaselineEstimator {
 public:
  explicit BaselineEstimator(const BaselineConfig& config);

  // One control period's sample.
  void add(const PeriodSample& s);

  [[nodiscard]] double rs_ohm() const { return theta_(0); }
  // Standard error of Rs from the RLS covariance and the residual variance.
  [[nodiscard]] double rs_std_ohm() const;
  [[nodiscard]] std::size_t updates() const { return updates_; }

 private:
  BaselineConfig config_;
  Eigen::Vector3d theta_;
  Eigen::Matrix3d p_;
  double lambda_;
  double residual_var_ = 1.0;
  std::size_t updates_ = 0;
  // Decimation accumulators.
  int count_ = 0;
  double y_ = 0.0;
  Eigen::Vector3d phi_ = Eigen::Vector3d::Zero();
};

}  // namespace pmsm::core
