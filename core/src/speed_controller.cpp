#include "pmsm/core/speed_controller.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace pmsm::core {

double pll_quantisation_speed_noise_rad_s(double pll_bandwidth_rad_s, double period_s, int encoder_bits) {
  const double count_rad = 2.0 * std::numbers::pi / std::ldexp(1.0, encoder_bits);
  return 2.0 * pll_bandwidth_rad_s * (1.0 + pll_bandwidth_rad_s * period_s) * count_rad / std::sqrt(12.0);
}

double speed_loop_quantisation_torque_Nm(double inertia_kg_m2, double bandwidth_rad_s, double pll_bandwidth_rad_s,
                                         double period_s, int encoder_bits) {
  return inertia_kg_m2 * bandwidth_rad_s * pll_quantisation_speed_noise_rad_s(pll_bandwidth_rad_s, period_s, encoder_bits);
}

double speed_bandwidth_for_quantisation_torque_rad_s(double torque_rms_Nm, double inertia_kg_m2,
                                                     double pll_bandwidth_rad_s, double period_s, int encoder_bits) {
  return torque_rms_Nm / (inertia_kg_m2 * pll_quantisation_speed_noise_rad_s(pll_bandwidth_rad_s, period_s, encoder_bits));
}

SpeedController::SpeedController(const SpeedControllerConfig& config) : config_(config) {
  // Plant J s: Kp = J wc gives crossover at wc; the zero at integral_ratio * wc keeps ~80 deg
  // of phase margin at crossover.
  const double kp = config.inertia_kg_m2 * config.bandwidth_rad_s;
  pi_.set_gains({kp, kp * config.integral_ratio * config.bandwidth_rad_s});
}

double SpeedController::step(double speed_ref_rad_s, double speed_meas_rad_s,
                             double torque_limit_Nm, bool current_loop_saturated, double feed_forward_Nm) {
  const double limit = std::min(torque_limit_Nm, config_.max_torque_Nm);
  double torque =
      pi_.update_clamped(speed_ref_rad_s - speed_meas_rad_s, config_.period_s, feed_forward_Nm, -limit, limit);
  if (current_loop_saturated) {
    torque -= pi_.hold(torque);  // no further integration away from zero torque
  }
  return torque;
}

}  // namespace pmsm::core
