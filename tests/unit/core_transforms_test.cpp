#include <gtest/gtest.h>

#include <cmath>

#include "pmsm/core/transforms.hpp"

namespace pmsm::core {
namespace {

TEST(Transforms, BalancedSetMapsToVectorOfPeakLength) {
  // A balanced set with peak 10 A leading by phi maps to a dq vector of length 10 A at phi
  // relative to the rotor (amplitude-invariant, Eq. 2).
  const double peak = 10.0;
  const double phi = 0.7;
  for (double theta : {0.0, 0.4, 2.0, 4.5, -1.3}) {
    const Abc x{peak * std::cos(theta + phi), peak * std::cos(theta + phi - 2.0 * kPi / 3.0),
                peak * std::cos(theta + phi + 2.0 * kPi / 3.0)};
    const Dq0 dq = abc_to_dq0(x, theta);
    EXPECT_NEAR(dq.d, peak * std::cos(phi), 1e-12);
    EXPECT_NEAR(dq.q, peak * std::sin(phi), 1e-12);
    EXPECT_NEAR(dq.zero, 0.0, 1e-12);
    // The fast Clarke + Park path agrees with the literal Eq. 2.
    const Dq fast = park(clarke(x), theta);
    EXPECT_NEAR(fast.d, dq.d, 1e-12);
    EXPECT_NEAR(fast.q, dq.q, 1e-12);
  }
}

TEST(Transforms, ZeroSequenceIsTheMean) {
  const Dq0 dq = abc_to_dq0({3.0, 3.0, 3.0}, 1.1);
  EXPECT_NEAR(dq.d, 0.0, 1e-12);
  EXPECT_NEAR(dq.q, 0.0, 1e-12);
  EXPECT_NEAR(dq.zero, 3.0, 1e-12);
}

TEST(Transforms, RoundTrips) {
  const Abc x{1.5, -0.25, -1.25};  // sums to zero
  const Abc back = inverse_clarke(clarke(x));
  EXPECT_NEAR(back.a, x.a, 1e-12);
  EXPECT_NEAR(back.b, x.b, 1e-12);
  EXPECT_NEAR(back.c, x.c, 1e-12);

  const Dq0 dq0{2.0, -3.0, 0.5};
  const Dq0 again = abc_to_dq0(dq0_to_abc(dq0, 0.9), 0.9);
  EXPECT_NEAR(again.d, 2.0, 1e-12);
  EXPECT_NEAR(again.q, -3.0, 1e-12);
  EXPECT_NEAR(again.zero, 0.5, 1e-12);

  const AlphaBeta ab{0.3, -0.8};
  const AlphaBeta ab2 = inverse_park(park(ab, 2.2), 2.2);
  EXPECT_NEAR(ab2.alpha, ab.alpha, 1e-12);
  EXPECT_NEAR(ab2.beta, ab.beta, 1e-12);
}

TEST(Transforms, DAxisAlignsWithPhaseAAtZeroAngle) {
  // At theta = 0 a current vector on d is phase a's peak.
  const Abc x = dq0_to_abc({5.0, 0.0, 0.0}, 0.0);
  EXPECT_NEAR(x.a, 5.0, 1e-12);
  EXPECT_NEAR(x.b, -2.5, 1e-12);
  EXPECT_NEAR(x.c, -2.5, 1e-12);
}

TEST(Transforms, AngleWrapping) {
  EXPECT_NEAR(wrap_angle_0_2pi(-0.5), kTwoPi - 0.5, 1e-12);
  EXPECT_NEAR(wrap_angle_0_2pi(7.0), 7.0 - kTwoPi, 1e-12);
  EXPECT_NEAR(wrap_angle_pm_pi(3.5), 3.5 - kTwoPi, 1e-12);
  EXPECT_NEAR(wrap_angle_pm_pi(-3.5), -3.5 + kTwoPi, 1e-12);
  EXPECT_GE(wrap_angle_0_2pi(-1e-18), 0.0);
  EXPECT_LT(wrap_angle_0_2pi(-1e-18), kTwoPi);
}

}  // namespace
}  // namespace pmsm::core
