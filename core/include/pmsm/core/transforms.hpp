// Reference-frame transforms, amplitude-invariant (the 2/3 factor of Eq. 2).
//
// Frames: abc phase quantities; alpha-beta (stator-stationary, the paper's qds frame, with
// alpha on the phase-a axis); dq (rotor frame, the paper's qdr, d on the magnet axis).
// theta is the electrical rotor angle from the phase-a axis to the d-axis. With the
// amplitude-invariant scaling a balanced set of phase currents with peak I maps to a
// vector of length I, so F (the injection vector magnitude) is a phase peak current.
#pragma once

#include <cmath>

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
struct Rotation {
  double c = 1.0;
  double s = 0.0;
};
// Both at a fixed cost of about 40 instructions, a quarter of libm's sin and cos: a
// Cody-Waite reduction by pi/2 (pi/2 in two parts, the first with 33 bits so that q * kHi is
// exact) and the minimax polynomials of fdlibm's kernels on [-pi/4, pi/4]. Within 2 ulp of the
// correctly rounded values (unit test TransformsTest.RotationMatchesLibm over [-1e5, 1e5]);
// outside that range, or for NaN and inf, it falls back to libm. The control step calls it up
// to three times a period (docs/performance.md).
[[nodiscard]] inline Rotation rotation(double angle_rad) {
  constexpr double kLimit = 1.0e5;                    // q * kHi stays exact far beyond this
  constexpr double kTwoOverPi = 0x1.45f306dc9c883p-1;
  constexpr double kHi = 0x1.921fb544p+0;             // pi/2, its first 33 bits
  constexpr double kLo = 0x1.0b4611a626331p-34;       // pi/2 - kHi
  if (!(std::abs(angle_rad) <= kLimit)) {
    return {std::cos(angle_rad), std::sin(angle_rad)};
  }
  const double y = angle_rad * kTwoOverPi;
  const int q = static_cast<int>(y >= 0.0 ? y + 0.5 : y - 0.5);  // nearest quadrant
  const double fq = static_cast<double>(q);
  const double r = (angle_rad - fq * kHi) - fq * kLo;  // in [-pi/4, pi/4] up to rounding
  const double z = r * r;
  const double sin_r =
      r + r * z *
              (-1.66666666666666324348e-01 +
               z * (8.33333333332248946124e-03 +
                    z * (-1.98412698298579493134e-04 +
                         z * (2.75573137070700676789e-06 +
                              z * (-2.50507602534068634195e-08 + z * 1.58969099521155010221e-10)))));
  const double cos_r =
      1.0 - 0.5 * z +
      z * z *
          (4.16666666666666019037e-02 +
           z * (-1.38888888888741095749e-03 +
                z * (2.48015872894767294178e-05 +
                     z * (-2.75573143513906633035e-07 +
                          z * (2.08757232129817482790e-09 + z * -1.13596475577881948265e-11)))));
  switch (q & 3) {
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
