#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numbers>
#include <random>

#include "pmsm/core/transforms.hpp"
#include "pmsm/fmod_two_pi.hpp"

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

TEST(Transforms, AngleWrappingMatchesFmodWithinATurnAndStaysInRangeFarOut) {
  // Within a turn of the range the fast path gives fmod's result bit for bit.
  for (const double x : {0.0, 1.0, kTwoPi, kTwoPi + 1e-9, 7.0, 12.5, 2.0 * kTwoPi - 1e-12, -1e-9, -0.5, -3.0, -6.28}) {
    double expected = std::fmod(x, kTwoPi);
    if (expected < 0.0) {
      expected += kTwoPi;
    }
    if (expected >= kTwoPi) {
      expected = 0.0;
    }
    EXPECT_EQ(wrap_angle_0_2pi(x), expected) << x;
  }
  // Far out (unwrapped angles of a long run): in range, and as close to fmod as the input
  // resolves.
  for (const double x : {1.0e3, -1.0e3, 3.7e6, -3.7e6, 1.0e9, 123456.789}) {
    const double w = wrap_angle_0_2pi(x);
    EXPECT_GE(w, 0.0) << x;
    EXPECT_LT(w, kTwoPi) << x;
    double expected = std::fmod(x, kTwoPi);
    if (expected < 0.0) {
      expected += kTwoPi;
    }
    EXPECT_NEAR(w, expected, 8.0 * std::abs(x) * std::numeric_limits<double>::epsilon()) << x;
  }
  EXPECT_TRUE(std::isnan(wrap_angle_0_2pi(std::numeric_limits<double>::quiet_NaN())));
  EXPECT_TRUE(std::isnan(wrap_angle_0_2pi(std::numeric_limits<double>::infinity())));
}

// The plant's angle reduction (common/math/pmsm/fmod_two_pi.hpp) against fmod, bit for bit:
// random angles out to ten million radians either side, the doubles next to the multiples of
// 2π (where x / 2π rounds to the wrong quotient), signed zeros, the largest fraction-carrying
// doubles and the fallback beyond them.
TEST(Transforms, FmodTwoPiIsFmodBitForBit) {
  constexpr double kTwoPi = 2.0 * std::numbers::pi;
  const auto same = [](double x) {
    const double want = std::fmod(x, kTwoPi);
    const double got = pmsm::math::fmod_two_pi(x);
    if (std::isnan(want)) {
      return std::isnan(got);
    }
    return std::bit_cast<std::uint64_t>(want) == std::bit_cast<std::uint64_t>(got);
  };
  std::mt19937_64 rng(2024);
  std::uniform_real_distribution<double> wide(-1e7, 1e7);
  std::uniform_real_distribution<double> near(-10.0, 10.0);
  int mismatches = 0;
  for (int i = 0; i < 200000; ++i) {
    const double x = (i % 2 == 0) ? wide(rng) : near(rng);
    mismatches += same(x) ? 0 : 1;
  }
  for (double k = -2e6; k <= 2e6; k += 997.0) {
    double x = k * kTwoPi;
    for (int u = 0; u < 4; ++u) {
      x = std::nextafter(x, -std::numeric_limits<double>::infinity());
    }
    for (int u = 0; u < 9; ++u) {
      mismatches += same(x) ? 0 : 1;
      x = std::nextafter(x, std::numeric_limits<double>::infinity());
    }
  }
  for (const double x : {0.0, -0.0, 1e-300, -1e-300, kTwoPi, -kTwoPi, 0x1p52 - 0.5, -0x1p52 + 0.5,
                         0x1p52, 1e300, -1e300, std::numeric_limits<double>::infinity(),
                         std::numeric_limits<double>::quiet_NaN()}) {
    EXPECT_TRUE(same(x)) << x;
  }
  EXPECT_EQ(mismatches, 0);
}

// The sine alone (the plant's cogging and ripples) is the pair's sine, bit for bit: a dense
// sweep of +-4 turns through every quadrant, a sparse one out to the limit and beyond, NaN.
TEST(Transforms, FixedSinIsFixedSinCosSine) {
  const auto same = [](double x) {
    const double want = pmsm::math::fixed_sincos(x).s;
    const double got = pmsm::math::fixed_sin(x);
    return std::isnan(want) ? std::isnan(got)
                            : std::bit_cast<std::uint64_t>(want) == std::bit_cast<std::uint64_t>(got);
  };
  int mismatches = 0;
  for (int i = -400000; i <= 400000; ++i) {
    mismatches += same(i * 6.2e-5) ? 0 : 1;
  }
  for (double x = 1.0; x < 4e6; x *= 1.0001) {
    mismatches += same(x) ? 0 : 1;
    mismatches += same(-x) ? 0 : 1;
  }
  for (const double x : {0.0, -0.0, std::numeric_limits<double>::infinity(), std::numeric_limits<double>::quiet_NaN()}) {
    EXPECT_TRUE(same(x)) << x;
  }
  EXPECT_EQ(mismatches, 0);
}

// The fixed-cost sincos (common/math/pmsm/fixed_sincos.hpp, also the plant's) against libm: a
// dense sweep of +-4 turns (where the control step calls it), its quadrant boundaries, a sparse
// sweep out to its limit (the plant's unwrapped angles), the fallback beyond it.
TEST(Transforms, RotationMatchesLibm) {
  constexpr double kUlp = std::numeric_limits<double>::epsilon();  // of 1.0
  double worst = 0.0;
  auto check = [&](double x) {
    const Rotation r = rotation(x);
    const double ec = std::abs(r.c - std::cos(x));
    const double es = std::abs(r.s - std::sin(x));
    // Absolute error, against libm's exactly reduced argument: the two-part pi/2 keeps the
    // reduction's own error near 1e-20 rad even at the limit.
    const double bound = 2.0 * kUlp;
    EXPECT_LE(ec, bound) << "cos " << x;
    EXPECT_LE(es, bound) << "sin " << x;
    if (std::abs(x) <= 8.0) {
      worst = std::max({worst, ec, es});
    }
  };
  for (int k = -200000; k <= 200000; ++k) {
    check(static_cast<double>(k) * (kTwoPi / 100000.0));
  }
  for (int q = -8; q <= 8; ++q) {
    for (const double d : {-1e-9, -1e-15, 0.0, 1e-15, 1e-9}) {
      check(q * (0.25 * kPi) + d);
    }
  }
  for (int k = -1000; k <= 1000; ++k) {
    check(static_cast<double>(k) * 1599.9991);  // out to the limit, 1.6e6 rad
  }
  EXPECT_LT(worst, kUlp);
  // Tiny angles keep their sine exactly (the small-angle rotations of the control step).
  EXPECT_EQ(rotation(1e-300).s, 1e-300);
  EXPECT_EQ(rotation(0.0).c, 1.0);
  EXPECT_EQ(rotation(-0.0).s, 0.0);
  // Beyond the limit and for non-finite angles: libm's answer.
  EXPECT_EQ(rotation(2e6).c, std::cos(2e6));
  EXPECT_EQ(rotation(-3e7).s, std::sin(-3e7));
  EXPECT_TRUE(std::isnan(rotation(std::numeric_limits<double>::quiet_NaN()).c));
  EXPECT_TRUE(std::isnan(rotation(std::numeric_limits<double>::infinity()).s));
}

TEST(Transforms, ComposedRotationsEqualTheRotationOfTheSum) {
  for (const double a : {0.0, 0.3, 2.0, -1.7, 5.9}) {
    for (const double b : {0.0, 1e-4, 0.047, -0.094, 3.0}) {
      const Rotation r = compose(rotation(a), rotation(b));
      EXPECT_NEAR(r.c, std::cos(a + b), 4e-16) << a << " " << b;
      EXPECT_NEAR(r.s, std::sin(a + b), 4e-16) << a << " " << b;
    }
  }
}


TEST(Transforms, SmallRotationIsTheRotationWithinAFewUlp) {
  constexpr double kUlp = std::numeric_limits<double>::epsilon();
  double worst = 0.0;
  for (int k = -25000; k <= 25000; ++k) {
    const double x = static_cast<double>(k) * (kSmallRotationRad / 25000.0);
    const Rotation r = small_rotation(x);
    worst = std::max({worst, std::abs(r.c - std::cos(x)), std::abs(r.s - std::sin(x))});
  }
  EXPECT_LE(worst, 4.0 * kUlp);
  // Beyond the series' range, and for NaN, the sincos itself.
  for (const double x : {0.2500001, -0.3, 2.0, 100.0}) {
    EXPECT_EQ(small_rotation(x).c, rotation(x).c) << x;
    EXPECT_EQ(small_rotation(x).s, rotation(x).s) << x;
  }
  EXPECT_TRUE(std::isnan(small_rotation(std::nan("")).c));
}
}  // namespace
}  // namespace pmsm::core
