// Reference-frame transforms, amplitude-invariant (the 2/3 factor of Eq. 2).
//
// Frames: abc phase quantities; alpha-beta (stator-stationary, the paper's qds frame, with
// alpha on the phase-a axis); dq (rotor frame, the paper's qdr, d on the magnet axis).
// theta is the electrical rotor angle from the phase-a axis to the d-axis. With the
// amplitude-invariant scaling a balanced set of phase currents with peak I maps to a
// vector of length I, so F (the injection vector magnitude) is a phase peak current.
#pragma once

#include <cmath>

#include "pmsm/fixed_sincos.hpp"

namespace pmsm::core {

struct Abc {
  double a = 0.0;
  double b = 0.0;
  double c = 0.0;
};

struct AlphaBeta {
  double alpha = 0.0;
  double beta = 0.0;
};

struct Dq {
  double d = 0.0;
  double q = 0.0;
};

struct Dq0 {
  double d = 0.0;
  double q = 0.0;
  double zero = 0.0;
};

inline constexpr double kPi = 3.14159265358979323846;
inline constexpr double kTwoPi = 2.0 * kPi;
inline constexpr double kSqrt3 = 1.73205080756887729353;

// Clarke transform (Eq. 2 at theta = 0), zero sequence discarded.
[[nodiscard]] constexpr AlphaBeta clarke(const Abc& x) {
  return {(2.0 * x.a - x.b - x.c) / 3.0, (x.b - x.c) / kSqrt3};
}

// Inverse Clarke transform; the zero-sequence component is taken as zero.
[[nodiscard]] constexpr Abc inverse_clarke(const AlphaBeta& x) {
  return {x.alpha, -0.5 * x.alpha + 0.5 * kSqrt3 * x.beta, -0.5 * x.alpha - 0.5 * kSqrt3 * x.beta};
}

// Park rotation from the stator frame into the rotor frame, given cos and sin of theta.
[[nodiscard]] constexpr Dq park(const AlphaBeta& x, double cos_theta, double sin_theta) {
  return {cos_theta * x.alpha + sin_theta * x.beta, -sin_theta * x.alpha + cos_theta * x.beta};
}

[[nodiscard]] constexpr AlphaBeta inverse_park(const Dq& x, double cos_theta, double sin_theta) {
  return {cos_theta * x.d - sin_theta * x.q, sin_theta * x.d + cos_theta * x.q};
}

// The full abc -> dq0 transform exactly as Eq. 2 writes it.
[[nodiscard]] Dq0 abc_to_dq0(const Abc& x, double theta_rad);

// Its inverse.
[[nodiscard]] Abc dq0_to_abc(const Dq0& x, double theta_rad);

// wrap_angle_0_2pi for an angle more than a turn outside the range, NaN or inf.
[[nodiscard]] double wrap_angle_0_2pi_far(double angle_rad);

// Wraps an angle into [0, 2*pi); NaN for NaN and inf. Within a turn of the range (nearly every
// call: the control step wraps angles that moved by less than a turn) one exact subtraction
// (Sterbenz: x - 2 pi is exact for x in [2 pi, 4 pi]) or the addition fmod's negative result
// would need: the same result as fmod, bit for bit. Further out: wrap_angle_0_2pi_far.
[[nodiscard]] inline double wrap_angle_0_2pi(double angle_rad) {
  double wrapped = angle_rad;
  if (wrapped >= kTwoPi) {
    wrapped -= kTwoPi;
  } else if (wrapped < 0.0) {
    wrapped += kTwoPi;
  }
  // The comparisons are false for NaN: it goes the far way too.
  if (wrapped >= 0.0 && wrapped < kTwoPi) {
    return wrapped;
  }
  return wrap_angle_0_2pi_far(angle_rad);
}

// A rotation by an angle as its cosine and sine: one sincos, and rotations by sums of angles
// by composition (exact up to rounding) instead of more sincos.
// The same pair as the shared sincos returns (cos c, sin s), so no copy between the two.
using Rotation = math::SinCos;
// At a fixed cost (common/math/pmsm/fixed_sincos.hpp): the control step calls it once a
// period, and small_rotation for the rest (docs/performance.md).
[[nodiscard]] inline Rotation rotation(double angle_rad) { return math::fixed_sincos(angle_rad); }
// The rotation by an angle that is usually small (a fraction of a period's advance, the gap
// between two estimates of one angle): the Taylor series to the eleventh power within
// kSmallRotationRad (truncation about 1e-16), about a third of a sincos; beyond it, and for
// NaN, the sincos. Within kShortSeriesRad, where the control step's angles are at most
// machines' speeds (half a period at 10 kHz up to 1,250 electrical rad/s), the series to the
// seventh power for the sine and the eighth for the cosine: its truncation, x^9/9! and
// x^10/10!, is below 5e-17 of x and below 3e-19, under half an ulp of each. It differs from
// the longer series in the last bit for a quarter of the angles up to kShortSeriesRad (one in
// 600 up to 0.03 rad), as each differs from sin and cos (test
// Transforms.SmallRotationIsTheRotationWithinAFewUlp); 11 instructions a control step fewer.
inline constexpr double kSmallRotationRad = 0.25;
inline constexpr double kShortSeriesRad = 0.0625;
[[nodiscard]] inline Rotation small_rotation(double angle_rad) {
  const double z = angle_rad * angle_rad;
  if (std::abs(angle_rad) <= kShortSeriesRad) {
    const double s = angle_rad * (1.0 + z * (-1.0 / 6.0 + z * (1.0 / 120.0 + z * (-1.0 / 5040.0))));
    const double c = 1.0 + z * (-0.5 + z * (1.0 / 24.0 + z * (-1.0 / 720.0 + z * (1.0 / 40320.0))));
    return {c, s};
  }
  if (!(std::abs(angle_rad) <= kSmallRotationRad)) {
    return rotation(angle_rad);
  }
  const double s =
      angle_rad *
      (1.0 + z * (-1.0 / 6.0 + z * (1.0 / 120.0 + z * (-1.0 / 5040.0 + z * (1.0 / 362880.0 + z * (-1.0 / 39916800.0))))));
  const double c =
      1.0 + z * (-0.5 + z * (1.0 / 24.0 + z * (-1.0 / 720.0 + z * (1.0 / 40320.0 + z * (-1.0 / 3628800.0)))));
  return {c, s};
}
// The rotation by the sum of the two angles.
[[nodiscard]] constexpr Rotation compose(const Rotation& a, const Rotation& b) {
  return {a.c * b.c - a.s * b.s, a.s * b.c + a.c * b.s};
}

[[nodiscard]] inline Dq park(const AlphaBeta& x, double theta_rad) {
  const Rotation r = rotation(theta_rad);
  return park(x, r.c, r.s);
}

[[nodiscard]] inline AlphaBeta inverse_park(const Dq& x, double theta_rad) {
  const Rotation r = rotation(theta_rad);
  return inverse_park(x, r.c, r.s);
}

// Wraps an angle into [-pi, pi).
[[nodiscard]] inline double wrap_angle_pm_pi(double angle_rad) {
  return wrap_angle_0_2pi(angle_rad + kPi) - kPi;
}

}  // namespace pmsm::core
