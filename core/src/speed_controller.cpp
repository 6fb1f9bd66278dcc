#include "pmsm/core/speed_controller.hpp"

#include <algorithm>

namespace pmsm::core {

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
