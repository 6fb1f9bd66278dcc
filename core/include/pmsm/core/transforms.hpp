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

[[nodiscard]] inline Dq park(const AlphaBeta& x, double theta_rad) {
  return park(x, std::cos(theta_rad), std::sin(theta_rad));
}

[[nodiscard]] constexpr AlphaBeta inverse_park(const Dq& x, double cos_theta, double sin_theta) {
  return {cos_theta * x.d - sin_theta * x.q, sin_theta * x.d + cos_theta * x.q};
}

[[nodiscard]] inline AlphaBeta inverse_park(const Dq& x, double theta_rad) {
  return inverse_park(x, std::cos(theta_rad), std::sin(theta_rad));
}

// The full abc -> dq0 transform exactly as Eq. 2 writes it.
[[nodiscard]] Dq0 abc_to_dq0(const Abc& x, double theta_rad);

// Its inverse.
[[nodiscard]] Abc dq0_to_abc(const Dq0& x, double theta_rad);

// Wraps an angle into [0, 2*pi).
[[nodiscard]] double wrap_angle_0_2pi(double angle_rad);

// A rotation by an angle as its cosine and sine: one sincos, and rotations by sums of angles
// by composition (exact up to rounding) instead of more sincos.
struct Rotation {
  double c = 1.0;
  double s = 0.0;
};
[[nodiscard]] inline Rotation rotation(double angle_rad) {
  return {std::cos(angle_rad), std::sin(angle_rad)};
}
// The rotation by the sum of the two angles.
[[nodiscard]] constexpr Rotation compose(const Rotation& a, const Rotation& b) {
  return {a.c * b.c - a.s * b.s, a.s * b.c + a.c * b.s};
}

// Wraps an angle into [-pi, pi).
[[nodiscard]] double wrap_angle_pm_pi(double angle_rad);

}  // namespace pmsm::core
