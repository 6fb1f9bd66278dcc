// std::fmod(x, 2π) bit for bit, at a constant cost. glibc's fmod costs more the further x lies
// from the range (a shift-and-subtract loop over the exponent difference), and the plant's rotor
// angle is unwrapped: after three simulated minutes at speed, its three fmods a period cost more
// than the sample they serve. The remainder x - n·2π for the true integer quotient n is exactly
// representable (that is why fmod is exact), so one fused multiply-add gives it exactly; x / 2π,
// rounded, can reach n + 1 just below a multiple of 2π (never below n: the division rounds
// monotonically and n is a double), which the sign check corrects; the other check is only
// defensive. Beyond
// 2^52 (no fraction left), and for NaN and inf, fmod's own. Unit test
// Transforms.FmodTwoPiIsFmodBitForBit.
#pragma once

#include <cmath>
#include <cstdint>
#include <numbers>

namespace pmsm::math {

[[nodiscard]] inline double fmod_two_pi(double x) {
  constexpr double kTwoPi = 2.0 * std::numbers::pi;
  if (x >= 0.0 && x < kTwoPi) {
    return x;  // -0.0 too, as fmod returns it
  }
  if (!(std::abs(x) < 0x1p52)) {
    return std::fmod(x, kTwoPi);
  }
  // trunc by the integer conversion (exact below 2^63): no library call.
  double n = static_cast<double>(static_cast<std::int64_t>(x / kTwoPi));
  double r = std::fma(-n, kTwoPi, x);
  // fmod's result has the sign of x and a magnitude below 2π.
  const double step = x < 0.0 ? -1.0 : 1.0;
  if (step * r < 0.0) {
    n -= step;
    r = std::fma(-n, kTwoPi, x);
  } else if (step * r >= kTwoPi) {
    n += step;
    r = std::fma(-n, kTwoPi, x);
  }
  return r == 0.0 ? std::copysign(0.0, x) : r;
}

}  // namespace pmsm::math
