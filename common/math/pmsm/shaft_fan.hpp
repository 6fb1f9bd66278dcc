// A shaft-mounted fan's share of a housing's path to the ambient (a self-ventilated, IC411
// machine), shared by the plant's thermal network and the drive's thermal model:
// standstill_share + (1 - standstill_share) (|w| / fan_speed)^exponent, the path being whole at
// the fan's speed, natural convection's share at rest, and |w| held at kFanSpeedSpan times the
// fan's speed beyond it (no extrapolation of the fan's air flow, and a bounded share, which the
// plant's explicit step and the drive's step check rely on). docs/plant.md section 6.3,
// docs/estimator.md section 7 ("A shaft fan").
#pragma once

#include <algorithm>
#include <cmath>

namespace pmsm::math {

inline constexpr double kFanSpeedSpan = 2.0;

// 1 exactly without a fan (fan_speed_rad_s not above 0).
[[nodiscard]] inline double shaft_fan_share(double omega_m_rad_s, double fan_speed_rad_s, double standstill_share,
                                            double exponent) {
  if (!(fan_speed_rad_s > 0.0)) {
    return 1.0;
  }
  const double w = std::min(std::abs(omega_m_rad_s), kFanSpeedSpan * fan_speed_rad_s);
  return standstill_share + (1.0 - standstill_share) * std::pow(w / fan_speed_rad_s, exponent);
}

}  // namespace pmsm::math
