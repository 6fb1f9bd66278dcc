// AngleTracker: encoder counts to angles, the PLL speed at constant speed and under
// constant acceleration, wrapping through count 0 in both directions.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "pmsm/core/angle_tracker.hpp"
#include "pmsm/core/speed_controller.hpp"
#include "pmsm/core/transforms.hpp"

namespace pmsm::core {
namespace {

constexpr int kBits = 14;
constexpr double kCounts = 16384.0;

std::uint32_t count_of(double theta_m) {
  const double turns = theta_m / kTwoPi;
  const double frac = turns - std::floor(turns);
  return static_cast<std::uint32_t>(std::floor(frac * kCounts)) % 16384U;
}

AngleTrackerConfig config() {
  AngleTrackerConfig c;
  c.encoder_bits = kBits;
  c.pole_pairs = 3;
  c.electrical_offset_rad = 0.4;
  c.pll_bandwidth_rad_s = 300.0;
  c.period_s = 1e-4;
  return c;
}

TEST(AngleTracker, AnglesFromCounts) {
  AngleTracker t(config());
  t.update(4096);  // a quarter turn, and the middle of that count's interval
  const double half_count = 0.5 * kTwoPi / kCounts;
  EXPECT_NEAR(t.mechanical_angle_rad(), kPi / 2.0 + half_count, 1e-12);
  EXPECT_NEAR(t.electrical_angle_rad(), wrap_angle_0_2pi(3.0 * (kPi / 2.0 + half_count) + 0.4), 1e-12);
  EXPECT_TRUE(t.initialised());
  EXPECT_EQ(t.mechanical_speed_rad_s(), 0.0);
  t.update(16383);
  EXPECT_LT(t.mechanical_angle_rad(), kTwoPi);
  EXPECT_GE(t.electrical_angle_rad(), 0.0);
  EXPECT_LT(t.electrical_angle_rad(), kTwoPi);
}

TEST(AngleTracker, TheElectricalAngleFromIntegerCountsIsTheWrappedProduct) {
  // The electrical angle is taken as (count x pole pairs) modulo the resolution, plus the
  // wrapped constant of the count's centre and the offset: the same angle as wrapping
  // pole_pairs x theta_m + offset, in [0, 2 pi), for any pole-pair count the keys admit, any
  // resolution, and offsets and corrections of either sign and beyond a turn.
  std::uint32_t seed = 12345U;
  const auto next = [&seed]() {
    seed = seed * 1664525U + 1013904223U;
    return seed;
  };
  for (const int bits : {10, 14, 20, 24}) {
    for (const int pp : {1, 3, 4, 7, 14, 64}) {
      for (const double offset : {0.0, 0.4, -2.9, 9.7}) {
        for (const double centre : {0.5, 0.0}) {
          AngleTrackerConfig c = config();
          c.encoder_bits = bits;
          c.pole_pairs = pp;
          c.electrical_offset_rad = offset;
          c.count_centre = centre;
          AngleTracker t(c);
          t.set_offset_correction_rad(offset < 0.0 ? -0.03 : 0.0);
          const double resolution = std::ldexp(1.0, bits);
          for (int k = 0; k < 200; ++k) {
            const std::uint32_t count = k < 2 ? (k == 0 ? 0U : static_cast<std::uint32_t>(resolution) - 1U)
                                              : next() % static_cast<std::uint32_t>(resolution);
            t.update(count);
            const double theta_m = (static_cast<double>(count) + centre) * kTwoPi / resolution;
            const double expected = wrap_angle_0_2pi(pp * theta_m + offset + t.offset_correction_rad());
            const double gap = std::abs(wrap_angle_pm_pi(t.electrical_angle_rad() - expected));
            ASSERT_LT(gap, 1e-12) << bits << " bits, " << pp << " pole pairs, offset " << offset << ", count " << count;
            ASSERT_GE(t.electrical_angle_rad(), 0.0);
            ASSERT_LT(t.electrical_angle_rad(), kTwoPi);
          }
        }
      }
    }
  }
}

TEST(AngleTracker, ConstantSpeedWithoutSteadyStateError) {
  for (double w : {100.0, -37.0}) {
    AngleTracker t(config());
    const double dt = 1e-4;
    double speed_error_sum = 0.0;
    double max_error = 0.0;
    double offset_first = 0.0;
    double offset_second = 0.0;
    double offset_min = 1e9;
    double offset_max = -1e9;
    int n = 0;
    for (int k = 0; k < 4000; ++k) {
      const double theta = 0.3 + w * k * dt;
      t.update(count_of(theta));
      if (k >= 2000) {  // 0.2 s: 60 loop time constants
        const double err = t.mechanical_speed_rad_s() - w;
        speed_error_sum += err;
        max_error = std::max(max_error, std::abs(err));
        ++n;
        // The smooth angle keeps a constant offset from the true angle (type 2: no drift).
        const double offset = t.smooth_unwrapped_electrical_angle_rad() - (3.0 * theta + 0.4);
        (k < 3000 ? offset_first : offset_second) += offset / 1000.0;
        offset_min = std::min(offset_min, offset);
        offset_max = std::max(offset_max, offset);
      }
    }
    EXPECT_NEAR(speed_error_sum / n, 0.0, 2e-3) << "w " << w;
    EXPECT_LT(max_error, 0.5) << "w " << w;
    EXPECT_NEAR(offset_first, offset_second, 1e-4) << "w " << w;
    EXPECT_LT(offset_max - offset_min, 3.0 * 2.0 * kTwoPi / kCounts) << "w " << w;  // two counts, electrical
    EXPECT_NEAR(t.electrical_speed_rad_s(), 3.0 * t.mechanical_speed_rad_s(), 1e-12);
  }
}

// Speed error after the loop has settled on a constant acceleration a (mechanical rad/s^2).
double settled_speed_error(double a, double* drift) {
  AngleTracker t(config());
  const double dt = 1e-4;
  const double w0 = 50.0;
  double err_early = 0.0;
  double err_late = 0.0;
  for (int k = 0; k <= 6000; ++k) {
    const double time = k * dt;
    const double theta = 0.1 + w0 * time + 0.5 * a * time * time;
    t.update(count_of(theta));
    const double err = t.mechanical_speed_rad_s() - (w0 + a * time);
    if (k > 3000 && k <= 3500) err_early += err / 500.0;
    if (k > 5500) err_late += err / 500.0;
  }
  *drift = err_late - err_early;
  return err_late;
}

TEST(AngleTracker, ConstantAccelerationGivesABoundedSpeedError) {
  // Type 2: under constant acceleration the error settles to a constant; it does not grow.
  for (double a : {200.0, -500.0}) {
    double drift = 0.0;
    const double err = settled_speed_error(a, &drift);
    EXPECT_LT(std::abs(drift), 0.02) << "a " << a;
    EXPECT_TRUE(std::isfinite(err));
  }
}

TEST(AngleTracker, WrapsThroughCountZeroInBothDirections) {
  AngleTracker t(config());
  const double count = kTwoPi / kCounts;
  t.update(16380);
  const double u0 = t.unwrapped_electrical_angle_rad();
  for (std::uint32_t c : {16382U, 0U, 2U, 4U}) t.update(c);
  EXPECT_NEAR(t.unwrapped_electrical_angle_rad() - u0, 3.0 * 8.0 * count, 1e-12);
  EXPECT_NEAR(t.mechanical_angle_rad(), 4.5 * count, 1e-15);
  EXPECT_GT(t.mechanical_speed_rad_s(), 0.0);
  // And back again.
  for (std::uint32_t c : {2U, 0U, 16382U, 16380U, 16378U}) t.update(c);
  EXPECT_NEAR(t.unwrapped_electrical_angle_rad() - u0, -3.0 * 2.0 * count, 1e-12);
  EXPECT_NEAR(t.mechanical_angle_rad(), 16378.5 * count, 1e-12);
}

TEST(AngleTracker, UnwrappedAngleAccumulatesOverManyTurns) {
  AngleTracker t(config());
  const double dt = 1e-4;
  const double w = 400.0;  // about 64 turns per second
  t.update(count_of(0.0));
  const double u0 = t.unwrapped_electrical_angle_rad();
  const int steps = 5000;  // 0.5 s: 200 rad, about 31.8 turns
  for (int k = 1; k <= steps; ++k) t.update(count_of(w * k * dt));
  const double theta_end = w * steps * dt;
  // The accumulated angle is the true one to within a count.
  EXPECT_NEAR(t.unwrapped_electrical_angle_rad() - u0, 3.0 * theta_end, 3.0 * kTwoPi / kCounts);
  EXPECT_NEAR(t.mechanical_speed_rad_s(), w, 0.5);
  // Backwards just as well.
  AngleTracker r(config());
  r.update(count_of(0.0));
  const double r0 = r.unwrapped_electrical_angle_rad();
  for (int k = 1; k <= steps; ++k) r.update(count_of(-w * k * dt));
  EXPECT_NEAR(r.unwrapped_electrical_angle_rad() - r0, -3.0 * theta_end, 3.0 * kTwoPi / kCounts);
  EXPECT_NEAR(r.mechanical_speed_rad_s(), -w, 0.5);
}

TEST(AngleTracker, ResetStartsAgainFromTheNextReading) {
  AngleTracker t(config());
  for (int k = 0; k < 1000; ++k) t.update(count_of(100.0 * k * 1e-4));
  EXPECT_GT(t.mechanical_speed_rad_s(), 50.0);
  t.reset();
  EXPECT_FALSE(t.initialised());
  EXPECT_EQ(t.mechanical_speed_rad_s(), 0.0);
  t.update(8192);  // half a turn
  EXPECT_TRUE(t.initialised());
  EXPECT_EQ(t.mechanical_speed_rad_s(), 0.0);
  const double at = kPi + 0.5 * kTwoPi / kCounts;  // the middle of count 8192
  EXPECT_NEAR(t.unwrapped_electrical_angle_rad(), wrap_angle_0_2pi(3.0 * at + 0.4), 1e-12);
  EXPECT_NEAR(t.smooth_unwrapped_electrical_angle_rad(), 3.0 * at + 0.4, 1e-12);
}

// A sensor outage while the shaft turns on (20 ms at 157 rad/s: half a turn unobserved). The
// drive resets the tracker (DriveController: no usable sample); the next reading locates the
// rotor and the one after gives the speed, so the loop restarts locked instead of acquiring
// from zero. Kept across the gap, the loop would read the half turn as one period's step.
TEST(AngleTracker, AfterAGapTheSpeedIsTheRotorsFromTheSecondReading) {
  const double w = 157.0;
  const double dt = 1e-4;
  AngleTracker t(config());
  AngleTracker kept(config());
  int k = 0;
  for (; k < 2000; ++k) {
    t.update(count_of(w * k * dt));
    kept.update(count_of(w * k * dt));
  }
  ASSERT_TRUE(t.speed_known());
  ASSERT_NEAR(t.mechanical_speed_rad_s(), w, 1.0);
  k += 200;  // 20 ms without a sample
  t.reset();
  EXPECT_FALSE(t.speed_known());
  t.update(count_of(w * k * dt));
  EXPECT_FALSE(t.speed_known()) << "one reading locates the rotor, it gives no speed";
  kept.update(count_of(w * k * dt));
  EXPECT_GT(std::abs(kept.mechanical_speed_rad_s() - w), 1000.0) << "the failure the reset prevents";
  double worst = 0.0;
  for (int n = 1; n <= 300; ++n) {
    t.update(count_of(w * (k + n) * dt));
    ASSERT_TRUE(t.speed_known());
    worst = std::max(worst, std::abs(t.mechanical_speed_rad_s() - w));
  }
  // One count a period (0.38 rad/s at 14 bits and 10 kHz) at the seed, less as the loop filters.
  EXPECT_LT(worst, 0.5);
}

// The encoder's advance over a period is that period's mean speed: it follows a speed
// transient the PLL lags (a pulse's own torque on a light rotor, docs/estimator.md 5.4), its
// quantization telescopes (the sum over any run of periods is the accumulated angle), and it is
// 0 at the first reading after a reset (no period before it).
TEST(AngleTracker, ThePeriodsStepIsItsMeanSpeedWithoutTheLoopsLag) {
  AngleTracker t(config());
  const double dt = 1e-4;
  auto theta_of = [](double time_s) {  // 100 rad/s, then +40 rad/s over 5 ms (8000 rad/s^2)
    const double ramp = std::clamp(time_s - 0.2, 0.0, 0.005);
    return 100.0 * time_s + 0.5 * 8000.0 * ramp * ramp + 40.0 * std::max(time_s - 0.205, 0.0);
  };
  t.update(count_of(theta_of(0.0)));
  EXPECT_EQ(t.last_step_electrical_rad(), 0.0);
  double sum = 0.0;
  const double u0 = t.unwrapped_electrical_angle_rad();
  double step_speed_error = 0.0;
  double pll_speed_error = 0.0;
  for (int k = 1; k <= 2060; ++k) {  // to 1 ms after the ramp's end
    t.update(count_of(theta_of(k * dt)));
    sum += t.last_step_electrical_rad();
    if (k >= 2000) {  // averaged over the last 6 ms, which hold the ramp: the period means
      step_speed_error += t.last_step_electrical_rad() / dt / 3.0 - (theta_of(k * dt) - theta_of((k - 1) * dt)) / dt;
      pll_speed_error += t.mechanical_speed_rad_s() - (theta_of(k * dt) - theta_of((k - 1) * dt)) / dt;
    }
  }
  EXPECT_NEAR(sum, t.unwrapped_electrical_angle_rad() - u0, 1e-9);
  // At most a count over the 61 periods (0.063 rad/s); the PLL lags the 40 rad/s step by more
  // than 5 rad/s on average over them.
  EXPECT_LT(std::abs(step_speed_error / 61.0), kTwoPi / kCounts / (61.0 * dt));
  EXPECT_GT(std::abs(pll_speed_error / 61.0), 5.0);
  t.reset();
  t.update(count_of(1.0));
  EXPECT_EQ(t.last_step_electrical_rad(), 0.0);
}

// A truncating encoder (count = floor(angle / resolution), as count_of() above and the plant
// emulator's encoder) reads half a count behind the rotor on average. Taken as the middle of its
// count's interval the reading is unbiased; taken as the count's lower edge it lags by half a
// count, which at speed rotates the voltage frame against the rotor's (docs/estimator.md, "The
// encoder's half count").
TEST(AngleTracker, ATruncatingEncoderIsReadWithoutBias) {
  const double count = kTwoPi / kCounts;
  for (const double centre : {0.5, 0.0}) {
    AngleTrackerConfig c = config();
    c.count_centre = centre;
    double error_sum = 0.0;
    const int n = 100000;
    for (int k = 0; k < n; ++k) {
      // Angles spread evenly over many counts (an irrational step), as a turning rotor gives.
      const double theta = std::fmod(0.1 + k * 0.0123456789, kTwoPi);
      AngleTracker t(c);
      t.update(count_of(theta));
      error_sum += t.mechanical_angle_rad() - theta;
    }
    const double mean_error_counts = error_sum / n / count;
    EXPECT_NEAR(mean_error_counts, centre - 0.5, 0.01) << "count_centre " << centre;
  }
}

// The loader's warning about the speed loop (drive/controller_config.cpp) rests on the PLL's
// speed noise from the encoder's rounding alone, 2 wn (1 + wn T) q / sqrt(12) RMS
// (core::pll_quantisation_speed_noise_rad_s): measured here on the tracker itself, turning at
// constant speed, for coarse and fine encoders, slow and fast loops and three periods (a replica
// in Python read 1.003-1.022 of it).
TEST(AngleTracker, ItsSpeedNoiseFromTheEncodersRoundingIsWhatTheSpeedLoopsWarningAssumes) {
  struct Case {
    int bits;
    double pll_rad_s;
    double period_s;
    double speed_rad_s;
  };
  for (const Case& c : {Case{14, 300.0, 1e-4, 101.3}, Case{10, 300.0, 1e-4, 23.7}, Case{14, 1000.0, 1e-4, -61.9},
                        Case{16, 100.0, 1.25e-4, 149.2}, Case{12, 300.0, 5e-5, 7.31}}) {
    AngleTrackerConfig cfg = config();
    cfg.encoder_bits = c.bits;
    cfg.pll_bandwidth_rad_s = c.pll_rad_s;
    cfg.period_s = c.period_s;
    AngleTracker t(cfg);
    const double counts = std::ldexp(1.0, c.bits);
    double sum = 0.0;
    double sum_sq = 0.0;
    int n = 0;
    for (int k = 0; k < 60000; ++k) {
      const double turns = (0.3 + c.speed_rad_s * k * c.period_s) / kTwoPi;
      t.update(static_cast<std::uint32_t>(std::floor((turns - std::floor(turns)) * counts)) %
               static_cast<std::uint32_t>(counts));
      if (k >= 20000) {  // settled: 20000 periods are 200 loop time constants or more
        const double e = t.mechanical_speed_rad_s() - c.speed_rad_s;
        sum += e;
        sum_sq += e * e;
        ++n;
      }
    }
    const double mean = sum / n;
    const double rms = std::sqrt(std::max(sum_sq / n - mean * mean, 0.0));
    const double model = pll_quantisation_speed_noise_rad_s(c.pll_rad_s, c.period_s, c.bits);
    EXPECT_EQ(speed_loop_quantisation_torque_Nm(1.0, 1.0, c.pll_rad_s, c.period_s, c.bits), model);
    EXPECT_GT(rms, 0.95 * model) << c.bits << " bits, " << c.pll_rad_s << " rad/s: measured " << rms;
    EXPECT_LT(rms, 1.05 * model) << c.bits << " bits, " << c.pll_rad_s << " rad/s: measured " << rms;
    // And the bandwidth for a torque noise is its inverse.
    EXPECT_NEAR(speed_bandwidth_for_quantisation_torque_rad_s(model * 2.0 * 3.0, 2.0, c.pll_rad_s, c.period_s, c.bits),
                3.0, 1e-9);
  }
}

}  // namespace
}  // namespace pmsm::core
