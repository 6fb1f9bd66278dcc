// Regression tests: behaviour the headers promise that an earlier version of core/ did not
// deliver (each test says what went wrong then). They guard the fixes.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>

#include "pmsm/core/angle_tracker.hpp"
#include "pmsm/core/injection_scheduler.hpp"
#include "pmsm/core/pair_estimator.hpp"
#include "pmsm/core/thermal_observer.hpp"
#include "pmsm/core/transforms.hpp"

namespace pmsm::core {
namespace {

std::uint32_t count_of(double theta_m) {
  const double turns = theta_m / kTwoPi;
  const double frac = turns - std::floor(turns);
  return static_cast<std::uint32_t>(std::floor(frac * 16384.0)) % 16384U;
}

AngleTrackerConfig tracker_config() {
  AngleTrackerConfig c;
  c.encoder_bits = 14;
  c.pole_pairs = 3;
  c.pll_bandwidth_rad_s = 300.0;
  c.period_s = 1e-4;
  return c;
}

// ISSUE angle-tracker-acceleration-lag: angle_tracker.hpp says the type-2 PLL "follows
// constant acceleration without a steady-state error". The reported speed is the loop's
// integrator, which lags a speed ramp by kp a / ki = 2 a / wn (3.3 rad/s mechanical at
// a = 500 rad/s^2, wn = 300 rad/s).
TEST(RegressionAngleTracker, SpeedFollowsConstantAccelerationWithoutError) {
  AngleTracker t(tracker_config());
  const double a = 500.0;
  double err = 0.0;
  for (int k = 0; k <= 6000; ++k) {
    const double time = k * 1e-4;
    t.update(count_of(0.1 + 50.0 * time + 0.5 * a * time * time));
    if (k > 5500) err += (t.mechanical_speed_rad_s() - (50.0 + a * time)) / 500.0;
  }
  EXPECT_NEAR(err, 0.0, 0.05) << "lag 2 a / wn = " << 2.0 * a / 300.0;
}

// ISSUE angle-tracker-smooth-angle-leads: smooth_unwrapped_electrical_angle_rad() returns the
// PLL's prediction for the NEXT sample (pll_theta is advanced by (speed + kp e) dt after the
// error is taken), so at constant speed it leads the encoder by w T: 0.03 rad electrical at
// 100 rad/s mechanical. drive_controller.cpp projects the dead-time pattern with it while the
// currents are projected with the encoder angle.
TEST(RegressionAngleTracker, SmoothAngleIsTheAngleOfTheLatestSample) {
  AngleTracker t(tracker_config());
  const double w = 100.0;
  double offset = 0.0;
  for (int k = 0; k < 4000; ++k) {
    const double theta = 0.3 + w * k * 1e-4;
    t.update(count_of(theta));
    if (k >= 3000) offset += (t.smooth_unwrapped_electrical_angle_rad() - 3.0 * theta) / 1000.0;
  }
  // The count is read at its middle (count_centre 0.5), so floor() leaves no mean offset; a
  // count (electrical: three) of room for the PLL's ripple.
  EXPECT_NEAR(offset, 0.0, 3.0 * kTwoPi / 16384.0) << "w T p = " << w * 1e-4 * 3.0;
}

// ISSUE thermal-nan-std: update_resistance(rs, NaN) passes the innovation gate (a comparison
// with NaN is false) and writes NaN into the state and covariance.
TEST(RegressionThermalObserver, NotANumberStandardErrorIsRejected) {
  ThermalObserver obs(ThermalModelConfig{}, Calibration{}, 40.0);
  const bool accepted = obs.update_resistance(0.15, std::nan(""));
  EXPECT_FALSE(accepted);
  EXPECT_TRUE(std::isfinite(obs.estimate().winding_C));
  EXPECT_TRUE(std::isfinite(obs.estimate().winding_std_C));
}

// ISSUE fit-zero-regressor (doubtful): with fit_ld on, a recording whose d(dId/dt) is exactly
// zero (flat fixed-magnitude pulse, noise-free currents) makes solve_fit invalid
// (solve_sums: xtx(r, r) <= 0 -> false), so the scheduler rejects a perfect pair as
// ill-conditioned. An unexcited regressor could be dropped instead.
TEST(RegressionPairFit, UnexcitedInductanceRegressorDoesNotInvalidateTheFit) {
  PairRecorder rec(1024);
  PairFitConfig cfg;
  rec.start(cfg, MatchBy::kAngle, 1.0);
  auto sample = [](double theta, double level) {
    PeriodSample s;
    s.theta_e_rad = theta;
    s.omega_e_rad_s = 300.0;
    s.omega_m_rad_s = 100.0;
    s.i_A = {level * 25.0, 0.0};
    s.dead_time_pattern = {level * (1.27 + 0.1 * std::cos(6.0 * theta)), 0.0};
    s.v_V = {0.15 * s.i_A.d + 1.5 * s.dead_time_pattern.d, 0.0};
    return s;
  };
  for (int k = 0; k < 215; ++k) rec.add_first(sample(0.4 + k * 0.03, 1.0));
  rec.begin_second(rec.first_origin() + 3.0 * kTwoPi);
  for (int k = 0; k < 220; ++k) rec.add_second(sample(0.4 + 3.0 * kTwoPi + (k + 0.4) * 0.03, -1.0));
  FitOptions o;
  o.fit_vx = false;
  o.fixed_vx_V = 1.5;
  o.fit_ld = true;
  const FitResult fit = solve_fit(rec.sums(), o);
  EXPECT_TRUE(fit.valid);
  EXPECT_NEAR(fit.rs_ohm, 0.15, 1e-9);
}

// budget() once reported kSkippedTorqueDisturbance whenever no other budget bound, even with
// the torque budget off on a round rotor. The torque reason must name the torque budget only.
TEST(RegressionScheduler, TorqueSkipOnlyWhenTheTorqueBudgetLimits) {
  InjectionConfig c;  // max_torque_disturbance_Nm = 0: no torque budget
  c.f_A = 35.0;
  c.current_limit_A = 80.0;
  InjectionScheduler s(c, 1e-4, 64);
  SchedulerInput in;
  in.omega_e_rad_s = 300.0;
  in.current_limit_A = 80.0;
  // Almost all of the current is motoring: sqrt(80^2 - 79.9^2) = 4 A of room for F.
  in.motoring_ref_A = {0.0, 79.9};
  const InjectionScheduler::Budget b = s.budget(in, c.tw_s, c.f_A);
  EXPECT_LT(b.f_A, c.f_min_A);
  EXPECT_EQ(b.limiting, PairOutcome::kRejectedCurrentLimit);

  // A salient machine with the budget on, at a modest load: now torque is the binding reason.
  c.max_torque_disturbance_Nm = 0.5;
  c.ld_H = 5.5e-3;
  c.lq_H = 8.25e-3;
  InjectionScheduler salient(c, 1e-4, 64);
  in.motoring_ref_A = {0.0, 40.0};  // 3/2 p dL iq = 0.495 Nm/A: F <= 1 A
  const InjectionScheduler::Budget t = salient.budget(in, c.tw_s, c.f_A);
  EXPECT_NEAR(t.f_A, 0.5 / (1.5 * 3 * 2.75e-3 * 40.0), 1e-9);
  EXPECT_EQ(t.limiting, PairOutcome::kSkippedTorqueDisturbance);
}

}  // namespace
}  // namespace pmsm::core
