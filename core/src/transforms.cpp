#include "pmsm/core/transforms.hpp"

#include <cmath>
#include <limits>

namespace pmsm::core {

Dq0 abc_to_dq0(const Abc& x, double theta_rad) {
  // Eq. 2: Sd = 2/3 [cos(t) Sa + cos(t - 2pi/3) Sb + cos(t + 2pi/3) Sc]
  //        Sq = 2/3 [-sin(t) Sa - sin(t - 2pi/3) Sb - sin(t + 2pi/3) Sc]
  //        S0 = 2/3 [Sa/2 + Sb/2 + Sc/2]
  constexpr double k120 = kTwoPi / 3.0;
  const double d = (2.0 / 3.0) * (std::cos(theta_rad) * x.a + std::cos(theta_rad - k120) * x.b +
                                  std::cos(theta_rad + k120) * x.c);
  const double q = (2.0 / 3.0) * (-std::sin(theta_rad) * x.a - std::sin(theta_rad - k120) * x.b -
                                  std::sin(theta_rad + k120) * x.c);
  const double zero = (x.a + x.b + x.c) / 3.0;
  return {d, q, zero};
}

Abc dq0_to_abc(const Dq0& x, double theta_rad) {
  constexpr double k120 = kTwoPi / 3.0;
  auto phase = [&](double shift) {
    return std::cos(theta_rad - shift) * x.d - std::sin(theta_rad - shift) * x.q + x.zero;
  };
  return {phase(0.0), phase(k120), phase(-k120)};
}

double wrap_angle_0_2pi_far(double angle_rad) {
  if (!std::isfinite(angle_rad)) {
    return std::numeric_limits<double>::quiet_NaN();
  }
  // Further out (an unwrapped angle after a long run): a constant-cost reduction, not fmod,
  // whose cost grows with the exponent difference. Its rounding, a few ulp of the input, is
  // below what the input itself resolves.
  double wrapped = angle_rad - kTwoPi * std::floor(angle_rad / kTwoPi);
  if (wrapped < 0.0) {
    wrapped += kTwoPi;
  }
  // A tiny negative number can round up to exactly 2*pi.
  return wrapped >= kTwoPi ? 0.0 : wrapped;
}

}  // namespace pmsm::core
