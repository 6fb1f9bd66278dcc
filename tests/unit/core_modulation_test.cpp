#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>
#include <tuple>

#include "pmsm/core/modulation.hpp"

namespace pmsm::core {
namespace {

// The average phase-to-neutral voltages an ideal bridge makes from the duties.
Abc phase_voltages(const Duties& d, double vdc) {
  const double mean = (d.value[0] + d.value[1] + d.value[2]) / 3.0 * vdc;
  return {d.value[0] * vdc - mean, d.value[1] * vdc - mean, d.value[2] * vdc - mean};
}

TEST(Svpwm, ProducesTheCommandedVoltageInsideTheLinearRange) {
  const double vdc = 650.0;
  const double linear_limit = vdc / std::sqrt(3.0);
  for (double magnitude : {0.0, 50.0, 200.0, 0.999 * linear_limit}) {
    for (int k = 0; k < 24; ++k) {
      const double angle = k * kTwoPi / 24.0 + 0.01;
      const AlphaBeta v{magnitude * std::cos(angle), magnitude * std::sin(angle)};
      const Duties d = svpwm(v, vdc);
      EXPECT_FALSE(d.clipped);
      const Abc expected = inverse_clarke(v);
      const Abc got = phase_voltages(d, vdc);
      EXPECT_NEAR(got.a, expected.a, 1e-9);
      EXPECT_NEAR(got.b, expected.b, 1e-9);
      EXPECT_NEAR(got.c, expected.c, 1e-9);
      // The common mode is centred: the largest and smallest duties are symmetric about 0.5.
      const double hi = std::max({d.value[0], d.value[1], d.value[2]});
      const double lo = std::min({d.value[0], d.value[1], d.value[2]});
      EXPECT_NEAR(hi + lo, 1.0, 1e-12);
    }
  }
}

TEST(Svpwm, ClipsBeyondTheHexagon) {
  const double vdc = 600.0;
  // Along a hexagon vertex direction (phase a axis) the hexagon reaches 2/3 Vdc.
  EXPECT_FALSE(svpwm({0.66 * vdc, 0.0}, vdc).clipped);
  EXPECT_TRUE(svpwm({0.68 * vdc, 0.0}, vdc).clipped);
  // Between vertices only Vdc / sqrt(3).
  const double a = kPi / 6.0;
  EXPECT_TRUE(svpwm({0.59 * vdc * std::cos(a), 0.59 * vdc * std::sin(a)}, vdc).clipped);
}

// On the drive's voltage limit (0.95 of the linear limit) the extreme duties are 0.025 from the
// rails. A phase there whose current takes the dead time from its pulse (positive at the low
// rail) is closer than 1.5 times a dead time of 2 us at 10 kHz (0.03): the bridge may not apply
// the command as it stands, although no duty clipped; with 1 us (0.015) it does. With the
// current the other way the dead time lengthens that pulse; near a zero crossing (inside the
// compensation's band) either sign counts.
TEST(DeadTimeCompensation, ADutyNearARailForItsDeadTimeIsFlagged) {
  const double vdc = 600.0, period = 1e-4;
  const AlphaBeta v = clarke(Abc{-0.475 * vdc, 0.475 * vdc, 0.0});  // 0.95 vdc / sqrt(3)
  auto flagged = [&](double dead_time_s, const Abc& i) {
    const DeadTimeCompensation comp{dead_time_s, 0.0, 1.0};
    const Abc correction = dead_time_compensation_V(i, i, comp, vdc, period);
    const Duties d = svpwm_corrected(v, vdc, correction);
    EXPECT_FALSE(d.clipped);
    return pulse_lost(d, correction, dead_time_error_V(comp, vdc, period), dead_time_s / period);
  };
  const Abc takes{10.0, 5.0, -15.0};     // phase a, at the low rail, positive
  const Abc lengthens{-10.0, 15.0, -5.0};  // phase a negative, phase b (the high rail) positive
  const Abc crossing{0.5, 5.0, -5.5};    // phase a inside the 1 A band
  EXPECT_TRUE(flagged(2e-6, takes));
  EXPECT_FALSE(flagged(1e-6, takes));
  EXPECT_FALSE(flagged(2e-6, lengthens));
  EXPECT_TRUE(flagged(2e-6, crossing));
}

TEST(DeadTimeCompensation, AddsTheExpectedVoltageAgainstTheCurrent) {
  const double vdc = 650.0, period = 1e-4;
  const DeadTimeCompensation comp{0.9e-6, 0.0, 1.0};
  const AlphaBeta v{100.0, -40.0};
  const Abc i{20.0, -5.0, -15.0};
  const Abc plain = phase_voltages(svpwm(v, vdc), vdc);
  const Abc corrected = phase_voltages(svpwm_compensated(v, vdc, i, i, comp, period), vdc);
  // Per-phase pole-voltage correction 0.9 us / 100 us * 650 V = 5.85 V with the sign of the
  // current; phase-to-neutral removes the mean of (+1, -1, -1) * 5.85 V.
  const double e = 5.85;
  const double mean = (e - e - e) / 3.0;
  EXPECT_NEAR(corrected.a - plain.a, e - mean, 1e-9);
  EXPECT_NEAR(corrected.b - plain.b, -e - mean, 1e-9);
  EXPECT_NEAR(corrected.c - plain.c, -e - mean, 1e-9);
  EXPECT_NEAR(soft_sign(0.25, 1.0), 0.25, 1e-12);
  EXPECT_NEAR(soft_sign(-7.0, 1.0), -1.0, 1e-12);
  EXPECT_EQ(soft_sign(0.0, 0.0), 0.0);
}

TEST(DeadTimeCompensation, MeanSoftSignIsTheTimeAverageOverALinearCurrent) {
  // Against a brute-force average of soft_sign along the straight line from i0 to i1.
  for (const auto& [i0, i1, band] : {std::tuple{-3.0, 2.0, 1.0}, std::tuple{-0.4, 0.7, 1.0}, std::tuple{5.0, 9.0, 1.0},
                                     std::tuple{2.0, -1.5, 0.75}, std::tuple{-1.0, 3.0, 0.0}, std::tuple{0.2, 0.2, 1.0}}) {
    double sum = 0.0;
    const int n = 200000;
    for (int k = 0; k < n; ++k) {
      sum += soft_sign(i0 + (i1 - i0) * (k + 0.5) / n, band);
    }
    EXPECT_NEAR(mean_soft_sign(i0, i1, band), sum / n, 1e-5) << i0 << " " << i1 << " " << band;
  }
  // A crossing in the middle of the period: half the time on each side.
  EXPECT_NEAR(mean_soft_sign(-5.0, 5.0, 1.0), 0.0, 1e-12);
}

// The sign pattern of noisy samples: over lines that pass the knees at every position (each
// phase passes both knees twice a turn), the plain mean of the measured currents reads the
// pattern's magnitude low; the corrected one has a few per cent of that bias left. Periods
// move 0.3, 1.1 and 3.3 A (the reference motor at the calibration's speed, at rated speed
// with 12 A, with 35 A); noise 0.2 A against the reference bridge's 0.75 A band.
TEST(DeadTimeCompensation, TheMeasuredSignPatternIsCorrectedForTheSamplesNoise) {
  const double band = 0.75;
  const double sigma = 0.2;
  std::mt19937_64 rng(7);
  std::normal_distribution<double> noise(0.0, sigma);
  for (const double span : {0.3, 1.1, 3.3}) {
    std::uniform_real_distribution<double> start(-band - span - 1.0, band + 1.0);
    double plain_bias = 0.0;
    double corrected_bias = 0.0;
    const int n = 200000;
    for (int k = 0; k < n; ++k) {
      const double i0 = start(rng);
      const double i1 = i0 + span;
      const double truth = mean_soft_sign(i0, i1, band);
      const double m0 = i0 + noise(rng);
      const double m1 = i1 + noise(rng);
      const double toward = i0 + i1 > 0.0 ? 1.0 : -1.0;  // the magnitude's direction
      plain_bias += toward * (mean_soft_sign(m0, m1, band) - truth);
      corrected_bias += toward * (mean_soft_sign_of_measured(m0, m1, band, std::sqrt(2.0 / 3.0) * sigma) - truth);
    }
    plain_bias /= n;
    corrected_bias /= n;
    EXPECT_LT(plain_bias, -1e-3) << "span " << span << ": the noise smooths the knees";
    EXPECT_LT(std::abs(corrected_bias), 0.25 * std::abs(plain_bias)) << "span " << span;
  }
  // No noise, or far from both knees: the plain mean exactly.
  EXPECT_EQ(mean_soft_sign_of_measured(-0.3, 0.9, band, 0.0), mean_soft_sign(-0.3, 0.9, band));
  EXPECT_EQ(mean_soft_sign_of_measured(4.0, 5.0, band, 0.16), 1.0);
  EXPECT_EQ(mean_soft_sign_of_measured(-0.1, 0.1, band, 0.05), mean_soft_sign(-0.1, 0.1, band));
  // A period that stays on a knee (no span) takes the density there, not a division by zero.
  EXPECT_TRUE(std::isfinite(mean_soft_sign_of_measured(band, band, band, 0.16)));
  EXPECT_GT(mean_soft_sign_of_measured(band, band, band, 0.16), 1.0 - 1e-12);
}

// The correction's normal CDF is interpolated from a table (modulation.cpp): against the same
// formula with libm's erfc, over lines of every span through and around both knees, including
// spans short enough that the difference quotient amplifies the table's error.
TEST(DeadTimeCompensation, TheNoiseCorrectionAgreesWithTheExactNormalCdf) {
  auto cdf = [](double z) { return z < -4.5 ? 0.0 : (z > 4.5 ? 1.0 : 0.5 * std::erfc(-z / std::sqrt(2.0))); };
  auto exact = [&](double i0, double i1, double b, double sigma) {
    auto along = [&](double x) {
      const double span = i1 - i0;
      const double z0 = (i0 - x) / sigma;
      if (std::abs(span) < 1e-3 * sigma) {
        return std::abs(z0) > 9.0 ? 0.0 : std::exp(-0.5 * z0 * z0) / (sigma * std::sqrt(2.0 * std::numbers::pi));
      }
      return (cdf((i1 - x) / sigma) - cdf(z0)) / span;
    };
    return sigma * sigma / (2.0 * b) * (along(b) - along(-b));
  };
  const double band = 0.75;
  double worst = 0.0;
  double largest = 0.0;
  for (const double sigma : {0.05, 0.16, 0.4}) {
    for (const double span : {-3.3, -0.4, -0.01, 2e-3, 0.05, 1.1}) {
      for (double i0 = -band - 3.0; i0 <= band + 3.0; i0 += 0.0137) {
        const double want = exact(i0, i0 + span, band, sigma);
        worst = std::max(worst, std::abs(soft_sign_noise_correction(i0, i0 + span, band, sigma) - want));
        largest = std::max(largest, std::abs(want));
      }
    }
  }
  // Lines that end exactly on the table's ends and its last node (z = +-4.5, just below 4.5).
  for (const double z : {-4.5, 4.5, std::nextafter(4.5, 0.0)}) {
    const double sigma = 1.0;
    const double i0 = band + z * sigma;
    for (const double span : {0.3, -0.3, 2e-3}) {
      const double want = exact(i0, i0 + span, band, sigma);
      worst = std::max(worst, std::abs(soft_sign_noise_correction(i0, i0 + span, band, sigma) - want));
    }
  }
  EXPECT_GT(largest, 0.05);      // the lines do pass the knees
  EXPECT_LT(worst, 1e-5 * largest) << "largest correction " << largest;
  EXPECT_TRUE(std::isnan(soft_sign_noise_correction(std::nan(""), 0.5, band, 0.16)));
}

TEST(DeadTimeCompensation, SoftSignMomentIsTheFirstMomentOverALinearCurrent) {
  // Against a brute-force integral of u soft_sign(i(u)), u in [-1/2, 1/2].
  for (const auto& [i0, i1, band] :
       {std::tuple{-3.0, 2.0, 1.0}, std::tuple{-0.4, 0.7, 1.0}, std::tuple{5.0, 9.0, 1.0}, std::tuple{2.0, -1.5, 0.75},
        std::tuple{-1.0, 3.0, 0.0}, std::tuple{0.2, 0.2, 1.0}, std::tuple{0.2, 0.2000001, 1.0},
        std::tuple{-0.9, -1.4, 1.0}, std::tuple{-6.0, -2.0, 0.75}}) {
    double sum = 0.0;
    const int n = 200000;
    for (int k = 0; k < n; ++k) {
      const double u = -0.5 + (k + 0.5) / n;
      sum += u * soft_sign(0.5 * (i0 + i1) + (i1 - i0) * u, band);
    }
    EXPECT_NEAR(soft_sign_moment(i0, i1, band), sum / n, 1e-5) << i0 << " " << i1 << " " << band;
  }
  // A sharp sign that rises through zero in the middle of the period: -1 before, +1 after,
  // the largest moment, 1/4; a constant sign has none.
  EXPECT_NEAR(soft_sign_moment(-5.0, 5.0, 0.0), 0.25, 1e-12);
  EXPECT_EQ(soft_sign_moment(3.0, 5.0, 1.0), 0.0);
}

}  // namespace
}  // namespace pmsm::core
