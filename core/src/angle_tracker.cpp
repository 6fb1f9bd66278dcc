#include "pmsm/core/angle_tracker.hpp"

#include "pmsm/core/transforms.hpp"

namespace pmsm::core {

AngleTracker::AngleTracker(const AngleTrackerConfig& config)
    : config_(config),
      offset_rad_(config.electrical_offset_rad),
      counts_to_rad_(kTwoPi / static_cast<double>(std::uint64_t{1} << config.encoder_bits)),
      // Critically damped type-2 loop: kp = 2 wn, ki = wn^2.
      kp_(2.0 * config.pll_bandwidth_rad_s),
      ki_(config.pll_bandwidth_rad_s * config.pll_bandwidth_rad_s) {}

void AngleTracker::reset() {
  initialised_ = false;
  speed_m_rad_s_ = 0.0;
  integrator_m_rad_s_ = 0.0;
  unwrapped_e_rad_ = 0.0;
  last_step_e_rad_ = 0.0;
}

void AngleTracker::update(std::uint32_t encoder_count) {
  // Counts beyond the encoder's range are wrapped into it (a corrupt reading must not put the
  // angle outside [0, 2 pi)).
  const std::uint64_t mask = (std::uint64_t{1} << config_.encoder_bits) - 1;  // a power of two
  theta_m_rad_ = (static_cast<double>(encoder_count & mask) + config_.count_centre) * counts_to_rad_;
  theta_e_rad_ = wrap_angle_0_2pi(config_.pole_pairs * theta_m_rad_ + offset_rad_);
  if (!initialised_) {
    initialised_ = true;
    previous_theta_m_rad_ = theta_m_rad_;
    pll_measured_unwrapped_rad_ = theta_m_rad_;
    pll_theta_rad_ = theta_m_rad_;
    smooth_m_rad_ = theta_m_rad_;
    unwrapped_e_rad_ = theta_e_rad_;
    last_step_e_rad_ = 0.0;
    return;
  }
  // Accumulate the measured angle: a step larger than half a turn between samples would need
  // more than 150 000 rpm at 10 kHz, so the shortest way round is the true one.
  const double step_m = wrap_angle_pm_pi(theta_m_rad_ - previous_theta_m_rad_);
  previous_theta_m_rad_ = theta_m_rad_;
  pll_measured_unwrapped_rad_ += step_m;
  last_step_e_rad_ = config_.pole_pairs * step_m;
  unwrapped_e_rad_ += last_step_e_rad_;

  // pll_theta_rad_ is the loop's prediction for this sample: that is the smooth angle now.
  // The loop's velocity is its integrator plus the proportional path; the integrator alone
  // lags a speed ramp by 2 a / wn.
  const double dt = config_.period_s;
  const double error = pll_measured_unwrapped_rad_ - pll_theta_rad_;
  smooth_m_rad_ = pll_theta_rad_;
  integrator_m_rad_s_ += ki_ * error * dt;
  speed_m_rad_s_ = integrator_m_rad_s_ + kp_ * error;
  pll_theta_rad_ += speed_m_rad_s_ * dt;
}

}  // namespace pmsm::core
