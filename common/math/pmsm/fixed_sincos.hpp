// cos and sin of one angle at a fixed cost of about 60 instructions, half of libm's sincos:
// a Cody-Waite reduction by pi/2 (pi/2 in two parts, the first with 33 bits so that q * kHi is
// exact for |q| < 2^20) and the minimax polynomials of fdlibm's kernels on [-pi/4, pi/4].
// Within 1 ulp of 1 of libm's values over a turn, and within a few ulp out to kLimit (unit test
// Transforms.RotationMatchesLibm); beyond kLimit, and for NaN and inf, libm's own.
// Shared by the controller (core/) and the plant emulator, which otherwise share no code.
#pragma once

#include <cmath>

namespace pmsm::math {

struct SinCos {
  double c = 1.0;
  double s = 0.0;
};

inline constexpr double kFixedSinCosLimit = 1.6e6;  // q = round(x 2/pi) stays below 2^20

namespace detail {

// The angle as q quarter turns plus r in [-pi/4, pi/4] (up to rounding), and r².
struct QuarterTurns {
  int q = 0;
  double r = 0.0;
  double z = 0.0;
};

[[nodiscard]] inline QuarterTurns reduce_quarter_turns(double angle_rad) {
  constexpr double kTwoOverPi = 0x1.45f306dc9c883p-1;
  constexpr double kHi = 0x1.921fb544p+0;        // pi/2, its first 33 bits
  constexpr double kLo = 0x1.0b4611a626331p-34;  // pi/2 - kHi
  const double y = angle_rad * kTwoOverPi;
  const int q = static_cast<int>(y >= 0.0 ? y + 0.5 : y - 0.5);  // nearest quadrant
  const double fq = static_cast<double>(q);
  const double r = (angle_rad - fq * kHi) - fq * kLo;
  return {q, r, r * r};
}

[[nodiscard]] inline double sin_kernel(double r, double z) {
  return r + r * z *
                 (-1.66666666666666324348e-01 +
                  z * (8.33333333332248946124e-03 +
                       z * (-1.98412698298579493134e-04 +
                            z * (2.75573137070700676789e-06 +
                                 z * (-2.50507602534068634195e-08 + z * 1.58969099521155010221e-10)))));
}

[[nodiscard]] inline double cos_kernel(double z) {
  return 1.0 - 0.5 * z +
         z * z *
             (4.16666666666666019037e-02 +
              z * (-1.38888888888741095749e-03 +
                   z * (2.48015872894767294178e-05 +
                        z * (-2.75573143513906633035e-07 +
                             z * (2.08757232129817482790e-09 + z * -1.13596475577881948265e-11)))));
}

}  // namespace detail

[[nodiscard]] inline SinCos fixed_sincos(double angle_rad) {
  if (!(std::abs(angle_rad) <= kFixedSinCosLimit)) {
    return {std::cos(angle_rad), std::sin(angle_rad)};
  }
  const detail::QuarterTurns a = detail::reduce_quarter_turns(angle_rad);
  const double sin_r = detail::sin_kernel(a.r, a.z);
  const double cos_r = detail::cos_kernel(a.z);
  switch (a.q & 3) {
    case 0:
      return {cos_r, sin_r};
    case 1:
      return {-sin_r, cos_r};
    case 2:
      return {-cos_r, -sin_r};
    default:
      return {sin_r, -cos_r};
  }
}

// fixed_sincos(angle_rad).s, bit for bit, with one kernel instead of two (the plant's cogging,
// load ripple and bus ripple want the sine alone; unit test Transforms.FixedSinIsFixedSinCosSine).
[[nodiscard]] inline double fixed_sin(double angle_rad) {
  if (!(std::abs(angle_rad) <= kFixedSinCosLimit)) {
    return std::sin(angle_rad);
  }
  const detail::QuarterTurns a = detail::reduce_quarter_turns(angle_rad);
  const double v = (a.q & 1) != 0 ? detail::cos_kernel(a.z) : detail::sin_kernel(a.r, a.z);
  return (a.q & 2) != 0 ? -v : v;
}

}  // namespace pmsm::math
