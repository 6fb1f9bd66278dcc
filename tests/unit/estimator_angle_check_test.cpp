// The calibration's rotor-angle check (angle_check.hpp) against a synthetic drive: a rotor of
// inertia J against friction and a load, held at its speed by the drive's own speed loop
// (SpeedController), whose current the controller puts where it believes the rotor's axes are:
// delta off the true ones. The torque is the rotor frame's, 3/2 p iq_r (psi + (Ld - Lq) id_r).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <random>

#include "pmsm/core/angle_check.hpp"
#include "pmsm/core/angle_tracker.hpp"
#include "pmsm/core/speed_controller.hpp"

namespace pmsm::core {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

struct Rotor {
  double delta_rad = 0.0;        // the controller's angle is this much behind the rotor's
  double psi_Wb = 0.3239;        // Table I: Ke 1.19 V s/rad
  double ld_minus_lq_H = 0.0;    // the true saliency
  int pole_pairs = 3;
  double inertia_kg_m2 = 0.00841;
  double friction_Nm = 0.908;    // Table I's Coulomb friction, at speed
  double viscous_Nm_s = 1e-3;
  double speed_rad_s = 60.0;     // mechanical, the speed loop's set-point
  double iq_noise_A = 0.2;       // on the measured current
  double load_step_at_s = -1.0;  // a load of load_step_Nm from then on
  double load_step_Nm = 0.0;
  bool speed_loop = true;        // false: torque control (the check must stand down)
  bool disable_at_01s = false;
  // 0: the speed loop and the check see the rotor's speed itself; otherwise the PLL's speed of
  // an encoder of this many bits (AngleTracker), starting at initial_angle_rad.
  int encoder_bits = 0;
  double pll_bandwidth_rad_s = 300.0;
  double initial_angle_rad = 0.0;
};

struct CheckRun {
  AngleCheckResult result;
  double duration_s = 0.0;
};

AngleCheckMotor model_of(const Rotor& r) {
  AngleCheckMotor m;
  m.flux_linkage_Wb = r.psi_Wb;
  m.ld_minus_lq_H = r.ld_minus_lq_H;
  m.pole_pairs = r.pole_pairs;
  m.inertia_kg_m2 = r.inertia_kg_m2;
  return m;
}

CheckRun run_check(const Rotor& r, const AngleCheckMotor& model, AngleCheckConfig cfg = {}) {
  constexpr double kT = 1e-4;
  constexpr int kDecimation = 10;
  SpeedControllerConfig sc;
  sc.period_s = kDecimation * kT;
  sc.inertia_kg_m2 = r.inertia_kg_m2;
  SpeedController speed(sc);
  const double kt = 1.5 * r.pole_pairs * r.psi_Wb;
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 1.0);
  double w = r.speed_rad_s;
  // Settled at the set-point before the check: the loop's integrator holds the friction.
  speed.reset(r.friction_Nm + r.viscous_Nm_s * w);
  double torque_demand = r.friction_Nm + r.viscous_Nm_s * w;
  AngleCheck check;
  check.start(cfg, model, kT);
  CheckRun run;
  AngleTrackerConfig encoder;
  encoder.encoder_bits = std::max(r.encoder_bits, 8);
  encoder.pole_pairs = r.pole_pairs;
  encoder.pll_bandwidth_rad_s = r.pll_bandwidth_rad_s;
  encoder.period_s = kT;
  AngleTracker tracker(encoder);
  const double counts = std::ldexp(1.0, encoder.encoder_bits);
  double theta_m = r.initial_angle_rad;
  const auto read_speed = [&]() {
    if (r.encoder_bits == 0) {
      return w;
    }
    const double turns = theta_m / (2.0 * std::numbers::pi);
    tracker.update(static_cast<std::uint32_t>(std::floor((turns - std::floor(turns)) * counts)) %
                   static_cast<std::uint32_t>(counts));
    return tracker.mechanical_speed_rad_s();
  };
  for (int i = 0; r.encoder_bits > 0 && i < 20000; ++i) {  // the PLL locked before the check
    (void)read_speed();
    theta_m += w * kT;
  }
  for (int k = 0; k < 200000; ++k) {
    const double t = k * kT;
    const double w_read = read_speed();
    if (r.speed_loop && k % kDecimation == 0) {
      torque_demand = speed.step(r.speed_rad_s, w_read, 1000.0);
    }
    const double id = check.id_ref_A();          // the current loop follows (steady state)
    const double iq = torque_demand / kt;
    const double c = std::cos(r.delta_rad);
    const double s = std::sin(r.delta_rad);
    const double id_r = id * c + iq * s;
    const double iq_r = iq * c - id * s;
    const double tem = 1.5 * r.pole_pairs * iq_r * (r.psi_Wb + r.ld_minus_lq_H * id_r);
    const double load = r.friction_Nm + r.viscous_Nm_s * w + (r.load_step_at_s >= 0.0 && t >= r.load_step_at_s ? r.load_step_Nm : 0.0);
    w += (tem - load) / r.inertia_kg_m2 * kT;
    theta_m += w * kT;
    const bool enabled = !(r.disable_at_01s && k == 1000);
    const double w_check = r.encoder_bits == 0 ? w : w_read;  // (the rotor's speed at the period's end)
    if (check.step(enabled, r.speed_loop, id, iq + r.iq_noise_A * noise(rng), w_check, r.pole_pairs * w_check)) {
      run.duration_s = t;
      break;
    }
  }
  run.result = check.result();
  return run;
}

TEST(AngleCheck, RecoversTheOffsetOfASurfaceMagnetRotor) {
  for (const double deg : {2.0, -1.0, 0.5, 0.0, 5.0}) {
    Rotor r;
    r.delta_rad = deg * kDeg;
    const CheckRun run = run_check(r, model_of(r));
    ASSERT_EQ(run.result.outcome, AngleCheckOutcome::kMeasured) << deg << " deg: " << to_string(run.result.outcome);
    // What the settled speed loop leaves, through the inertia term, and the noise: a hundredth
    // of a degree, against the 0.5 degree that failed the reference's calibration.
    EXPECT_NEAR(run.result.offset_rad, r.delta_rad, 0.01 * kDeg) << deg << " deg";
    EXPECT_LT(run.result.offset_std_rad, 0.01 * kDeg);
    EXPECT_NEAR(run.result.d_id_A, 50.0, 0.5) << "+25 A against -25 A";
    EXPECT_LT(run.duration_s, 0.6) << "three levels of settle and average, and the solve";
  }
}

TEST(AngleCheck, TheInertiaTermCoversASpeedLoopThatHasNotSettled) {
  // A third of the default settle: the speed loop is still answering each level's torque, and
  // J dw/dt carries the difference. Without it the answer would be about 15 % short.
  Rotor r;
  r.delta_rad = 2.0 * kDeg;
  AngleCheckConfig cfg;
  cfg.settle_s = 0.033;
  const CheckRun run = run_check(r, model_of(r), cfg);
  ASSERT_EQ(run.result.outcome, AngleCheckOutcome::kMeasured) << to_string(run.result.outcome);
  EXPECT_NEAR(run.result.offset_rad, r.delta_rad, 0.03 * r.delta_rad);
  AngleCheckMotor no_inertia = model_of(r);
  no_inertia.inertia_kg_m2 = 0.0;
  const CheckRun without = run_check(r, no_inertia, cfg);
  EXPECT_GT(std::abs(without.result.offset_rad - r.delta_rad), 3.0 * std::abs(run.result.offset_rad - r.delta_rad))
      << "the inertia term is what makes the short settle work";
}

TEST(AngleCheck, ASalientRotorWithItsSaliencyKnown) {
  // The salient benchmark's machine (Lq = 1.5 Ld): the levels' reluctance torque against the
  // friction's q current is in the balance.
  Rotor r;
  r.ld_minus_lq_H = 5.5e-3 - 8.25e-3;
  r.delta_rad = -1.5 * kDeg;
  const CheckRun run = run_check(r, model_of(r));
  ASSERT_EQ(run.result.outcome, AngleCheckOutcome::kMeasured) << to_string(run.result.outcome);
  EXPECT_NEAR(run.result.offset_rad, r.delta_rad, 0.01 * kDeg);
}

TEST(AngleCheck, AnErrorInTheSaliencyReadsAsAnOffsetInsideTheModelsErrorBar) {
  // Commissioned Ld +10 % and Lq -10 % on that machine: the model's Ld - Lq is half the true one.
  // The error times the friction's q current over psi reads as offset; the result says how much
  // it can be, and the drive corrects only beyond three times that (drive_controller.cpp).
  Rotor r;
  r.ld_minus_lq_H = 5.5e-3 - 8.25e-3;
  r.delta_rad = 0.0;
  AngleCheckMotor model = model_of(r);
  model.ld_minus_lq_H = 6.05e-3 - 7.425e-3;
  model.saliency_std_H = 0.1 * std::hypot(6.05e-3, 7.425e-3);
  const CheckRun run = run_check(r, model);
  ASSERT_EQ(run.result.outcome, AngleCheckOutcome::kMeasured) << to_string(run.result.outcome);
  const double iq0 = r.friction_Nm / (1.5 * r.pole_pairs * r.psi_Wb);
  const double expected_bias = (r.ld_minus_lq_H - model.ld_minus_lq_H) * iq0 / r.psi_Wb;
  EXPECT_NEAR(run.result.offset_rad, -expected_bias, 0.2 * std::abs(expected_bias) + 0.01 * kDeg)
      << "the reluctance term's error, as derived";
  EXPECT_GT(3.0 * run.result.model_std_rad, std::abs(run.result.offset_rad)) << "inside the error bar: not corrected";
}

TEST(AngleCheck, AtRestItIsNotChecked) {
  Rotor r;
  r.speed_rad_s = 0.0;
  const CheckRun run = run_check(r, model_of(r));
  EXPECT_EQ(run.result.outcome, AngleCheckOutcome::kNotTurning);
  EXPECT_EQ(run.duration_s, 0.0) << "at once, without injecting";
}

TEST(AngleCheck, InTorqueControlItStandsDown) {
  Rotor r;
  r.speed_loop = false;
  const CheckRun run = run_check(r, model_of(r));
  EXPECT_EQ(run.result.outcome, AngleCheckOutcome::kNoSpeedLoop);
}

TEST(AngleCheck, DisablingTheDriveAbortsIt) {
  Rotor r;
  r.disable_at_01s = true;
  const CheckRun run = run_check(r, model_of(r));
  EXPECT_EQ(run.result.outcome, AngleCheckOutcome::kAborted);
  AngleCheck check;
  check.start(AngleCheckConfig{}, model_of(r), 1e-4);
  EXPECT_TRUE(check.step(true, true, 0.0, std::nan(""), 60.0, 180.0)) << "a non-finite input";
  EXPECT_EQ(check.result().outcome, AngleCheckOutcome::kAborted);
  EXPECT_EQ(check.id_ref_A(), 0.0);
}

TEST(AngleCheck, ALoadThatMovesDuringTheCheckVoidsIt) {
  // A load step in the last +L level's settle (0.36 s of its 0.38 s): the speed loop is still
  // answering it in that level's average, and the two +L levels disagree.
  Rotor r;
  r.delta_rad = 1.0 * kDeg;
  r.load_step_at_s = 0.36;
  r.load_step_Nm = 2.0;
  const CheckRun run = run_check(r, model_of(r));
  EXPECT_TRUE(run.result.outcome == AngleCheckOutcome::kUnsteady || run.result.outcome == AngleCheckOutcome::kSpeedChanged)
      << to_string(run.result.outcome);
}

TEST(AngleCheck, TensOfDegreesAreRefusedNotCorrected) {
  Rotor r;
  r.delta_rad = 30.0 * kDeg;
  const CheckRun run = run_check(r, model_of(r));
  EXPECT_EQ(run.result.outcome, AngleCheckOutcome::kOutOfRange);
  EXPECT_NEAR(run.result.offset_rad, r.delta_rad, 0.1 * kDeg) << "still measured, for the message";
}

// A heavy rotor on a 14-bit encoder: the speed loop's gain (J x 60 rad/s) makes 12 % of its
// rated torque of the PLL's speed noise (a press on a flywheel, docs/accuracy.md, ninth round).
// The check's readings of an exact encoder then scatter by about a degree, far wider than the
// two +L levels' disagreement can say (one degree of freedom): on the press it read 1.5-10 mrad
// where the readings scattered 12 mrad, and 2 of 16 seeds were corrected by 16 and 22 mrad.
// speed_std_rad, what the speed's noise leaves in J dw/dt, is the floor the drive takes
// (DriveController::finish_angle_check): it predicts the scatter, and no reading passes three
// times it.
TEST(AngleCheck, TheSpeedsNoiseIsAFloorUnderItsErrorBar) {
  Rotor r;
  r.psi_Wb = 0.432;  // Kt 2.59 N m/A
  r.pole_pairs = 4;
  r.inertia_kg_m2 = 1.38;
  r.friction_Nm = 2.0;
  r.speed_rad_s = 40.0;
  r.encoder_bits = 14;
  AngleCheckConfig cfg;
  cfg.level_A = 10.0;
  cfg.speed_noise_rad_s = pll_quantisation_speed_noise_rad_s(r.pll_bandwidth_rad_s, 1e-4, r.encoder_bits);
  double sum_sq = 0.0;
  double floor_sum = 0.0;
  int n = 0;
  int passed_own = 0;
  for (int i = 0; i < 12; ++i) {
    r.initial_angle_rad = 0.37 * i;
    r.speed_rad_s = 40.0 + 0.173 * i;
    const CheckRun run = run_check(r, model_of(r), cfg);
    if (run.result.outcome != AngleCheckOutcome::kMeasured) {
      continue;
    }
    const AngleCheckResult& a = run.result;
    sum_sq += a.offset_rad * a.offset_rad;
    floor_sum += a.speed_std_rad;
    ++n;
    EXPECT_LT(std::abs(a.offset_rad), 3.0 * std::max(a.offset_std_rad, a.speed_std_rad)) << "start " << r.initial_angle_rad;
    passed_own += std::abs(a.offset_rad) >= 3.0 * a.offset_std_rad ? 1 : 0;
  }
  ASSERT_GE(n, 8) << "most checks measure";
  const double scatter = std::sqrt(sum_sq / n);
  const double predicted = floor_sum / n;
  EXPECT_GT(scatter, 0.003) << "the speed loop's noise makes a scatter of milliradians";
  // Within a factor of two at this 60 rad/s speed loop (1.5 times it here, 0.83 times it on the
  // press in closed loop); the floor does not follow the loop's bandwidth (angle_check.cpp).
  EXPECT_GT(predicted, 0.5 * scatter);
  EXPECT_LT(predicted, 2.0 * scatter);
  // And the levels' own error bar alone would have let some through (4 of 10 here).
  EXPECT_GE(passed_own, 1);
  // On the rotor's own speed the floor is nothing to speak of.
  Rotor exact = r;
  exact.encoder_bits = 0;
  const CheckRun ideal = run_check(exact, model_of(exact), cfg);
  ASSERT_EQ(ideal.result.outcome, AngleCheckOutcome::kMeasured);
  EXPECT_LT(std::abs(ideal.result.offset_rad), 0.1 * scatter);
}

}  // namespace
}  // namespace pmsm::core
