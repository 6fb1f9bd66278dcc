#include "pmsm/core/current_controller.hpp"

#include <algorithm>
#include <cmath>

namespace pmsm::core {

CurrentController::CurrentController(const CurrentControllerConfig& config) : config_(config) {
  auto gains = [&](double l_H) {
    const double kp = config.bandwidth_rad_s * l_H;
    const double zero_rad_s = std::max(config.rs_ohm / l_H, config.integral_zero_fraction * config.bandwidth_rad_s);
    return PiGains{kp, kp * zero_rad_s};
  };
  pi_d_.set_gains(gains(config.ld_H));
  pi_q_.set_gains(gains(config.lq_H));
}

void CurrentController::reset() {
  pi_d_.reset();
  pi_q_.reset();
  status_ = {};
}

const CurrentControllerStatus& CurrentController::step(const Dq& i_ref_A, const Dq& i_meas_A,
                                                       double omega_e_rad_s, double vdc_V) {
  const double dt = config_.period_s;

  // Feed-forward of Eq. 3's cross-coupling and EMF terms, from the measured currents.
  // Coupling from the references would be smoother, but when a reference is out of reach (the
  // voltage limit at speed) it injects a voltage for a current that does not flow and drags
  // the other axis away. The resistive drop is left to the integral, whose gain wc Rs makes
  // exactly that (pole-zero cancellation); feeding it forward as well would double it.
  Dq feed_forward{};
  if (config_.decoupling) {
    feed_forward.d = -omega_e_rad_s * config_.lq_H * i_meas_A.q;
    feed_forward.q = omega_e_rad_s * (config_.ld_H * i_meas_A.d + config_.flux_linkage_Wb);
  }

  const Dq unlimited{pi_d_.update(i_ref_A.d - i_meas_A.d, dt) + feed_forward.d,
                     pi_q_.update(i_ref_A.q - i_meas_A.q, dt) + feed_forward.q};

  // Circle limit with d-axis priority: the d-axis voltage carries the injection signal and
  // field weakening, so it is served first and the q-axis gets what is left.
  const double limit = voltage_limit_V(vdc_V);
  Dq limited = unlimited;
  limited.d = std::clamp(limited.d, -limit, limit);
  const double q_room = std::sqrt(std::max(limit * limit - limited.d * limited.d, 0.0));
  limited.q = std::clamp(limited.q, -q_room, q_room);

  pi_d_.limit_to(limited.d, unlimited.d);
  pi_q_.limit_to(limited.q, unlimited.q);

  status_.v_V = limited;
  status_.v_unlimited_V = unlimited;
  status_.voltage_limited = limited.d != unlimited.d || limited.q != unlimited.q;
  status_.voltage_limit_V = limit;
  return status_;
}

}  // namespace pmsm::core
