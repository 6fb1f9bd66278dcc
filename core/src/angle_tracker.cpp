#include "pmsm/core/angle_tracker.hpp"

#include "pmsm/core/transforms.hpp"

namespace pmsm::core {

AngleTracker::AngleTracker(const AngleTrackerConfig& config)
    : config_(config),
      offset_rad_(config.electrical_offset_rad),
      counts_to_rad_(kTwoPi / static_cast<double>(std::uint64_t{1} << config.encoder_bits)),
      // Critically damped type-2 loop: kp = 2 wn, ki = wn^2.
      kp_(2.0 * config.pll_bandwidth_rad_s),
      ki_(config.pll_bandwidth_rad_s * config.pll_bandwidth_rad_s),
      electrical_base_rad_(electrical_base_rad()) {}

double AngleTracker::electrical_base_rad() const {
  return wrap_angle_0_2pi(config_.pole_pairs * config_.count_centre * counts_to_rad_ + offset_rad_);
}

void AngleTracker::reset() {
  initialised_ = false;
  speed_known_ = false;
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
  // The electrical angle within a turn from the count itself: (count x pole pairs) modulo the
  // encoder's resolution is the electrical turn's fraction exactly, in integers (the motor
  // keys hold 1..64 pole pairs), and the centre and offset's constant part is already wrapped,
  // so one comparison wraps the sum. Wrapping pole_pairs x theta_m in floating point cost a
  // division and a floor on most periods (up to 64 turns; docs/performance.md).
  const double within_turn_rad =
      static_cast<double>((std::uint64_t{encoder_count & mask} * static_cast<std::uint64_t>(config_.pole_pairs)) & mask) *
          counts_to_rad_ +
      electrical_base_rad_;
  theta_e_rad_ = within_turn_rad >= kTwoPi ? within_turn_rad - kTwoPi : within_turn_rad;
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
  if (!speed_known_) {
    // The second sample: the encoder's advance over the period is the speed (to a count a
    // period, 0.38 rad/s at 14 bits and 10 kHz), and the loop starts locked on it.
    speed_known_ = true;
    smooth_m_rad_ = pll_measured_unwrapped_rad_;
    integrator_m_rad_s_ = step_m / dt;
    speed_m_rad_s_ = integrator_m_rad_s_;
    pll_theta_rad_ = pll_measured_unwrapped_rad_ + speed_m_rad_s_ * dt;
    return;
  }
  const double error = pll_measured_unwrapped_rad_ - pll_theta_rad_;
  smooth_m_rad_ = pll_theta_rad_;
  integrator_m_rad_s_ += ki_ * error * dt;
  speed_m_rad_s_ = integrator_m_rad_s_ + kp_ * error;
  pll_theta_rad_ += speed_m_rad_s_ * dt;
}

}  // namespace pmsm::core
