// ThermalObserver and derate(): the prediction against the analytic two-node response, the
// Kalman update against a gain computed by hand, the innovation gate, time-to-limit against a
// brute-force simulation.
#include <gtest/gtest.h>

#include <array>
#include <functional>
#include <random>

#include <vector>

#include <Eigen/Dense>
#include <cmath>
#include <limits>

#include "pmsm/core/machine_equations.hpp"
#include "pmsm/core/thermal_observer.hpp"

namespace pmsm::core {
namespace {

constexpr double kAlpha = alpha_at_C(25.0);  // Eq. 1, copper, referred to the calibration's T0 = 25 C

// The two-node network written out here: winding (Cw) and housing (Ch), Rwh between them,
// Rha to ambient; copper loss on the winding with Rs(Tw) from Eq. 1, iron loss on the housing.
struct Network {
  double cw, ch, rwh, rha;
  double rs0, t0;
};

Network network_of(const ThermalModelConfig& c, const Calibration& cal) {
  return {c.winding_capacity_J_K, c.housing_capacity_J_K, c.winding_to_housing_K_W, c.housing_to_ambient_K_W,
          cal.rs0_ohm, cal.t0_C};
}

// x' = A x + b, copper loss affine in Tw: Pcu = 1.5 I2 Rs0 (1 + alpha (Tw - T0)).
void linear_system(const Network& n, double i2, double p_iron, double ambient, Eigen::Matrix2d& a, Eigen::Vector2d& b) {
  const double gwh = 1.0 / n.rwh;
  const double gha = 1.0 / n.rha;
  const double k = 1.5 * i2 * n.rs0;
  a << (-gwh + k * kAlpha) / n.cw, gwh / n.cw, gwh / n.ch, -(gwh + gha) / n.ch;
  b << k * (1.0 - kAlpha * n.t0) / n.cw, (p_iron + gha * ambient) / n.ch;
}

// x(t) = x_ss + V exp(L t) V^-1 (x0 - x_ss).
Eigen::Vector2d analytic(const Eigen::Matrix2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& x0, double t) {
  const Eigen::Vector2d xss = -a.inverse() * b;
  const Eigen::EigenSolver<Eigen::Matrix2d> eig(a);
  const Eigen::Matrix2cd v = eig.eigenvectors();
  const Eigen::Vector2cd l = eig.eigenvalues();
  Eigen::Matrix2cd e = Eigen::Matrix2cd::Zero();
  e(0, 0) = std::exp(l(0) * t);
  e(1, 1) = std::exp(l(1) * t);
  const Eigen::Vector2cd d = (x0 - xss).cast<std::complex<double>>();
  return xss + (v * e * v.inverse() * d).real();
}

TEST(ThermalObserver, PredictionFollowsTheTwoNodeResponseWithIronLossOnly) {
  ThermalModelConfig c;
  Calibration cal;
  ThermalObserver obs(c, cal, 25.0);
  const double w = 200.0;
  const double p_iron = c.iron_loss_k1_W_s_rad * w + c.iron_loss_k2_W_s2_rad2 * w * w;  // 160 W
  EXPECT_DOUBLE_EQ(obs.iron_loss_W(-w), p_iron);  // |w|
  Eigen::Matrix2d a;
  Eigen::Vector2d b;
  linear_system(network_of(c, cal), 0.0, p_iron, 40.0, a, b);
  const double dt = 0.5;  // far below the 132 s winding time constant
  int step = 0;
  for (double t_check : {60.0, 600.0, 3000.0, 12000.0}) {
    while (step * dt < t_check - 1e-9) {
      obs.predict(dt, 0.0, w, 40.0);
      ++step;
    }
    const Eigen::Vector2d x = analytic(a, b, Eigen::Vector2d(25.0, 25.0), t_check);
    EXPECT_NEAR(obs.estimate().winding_C, x(0), 0.01) << "t " << t_check;
    EXPECT_NEAR(obs.estimate().housing_C, x(1), 0.01) << "t " << t_check;
  }
  // Steady state (the slow time constant is about 2600 s): housing = ambient + P Rha, and the
  // winding at the housing temperature (no copper loss).
  for (int k = 0; k < 20000; ++k) obs.predict(2.0, 0.0, w, 40.0);
  EXPECT_NEAR(obs.estimate().housing_C, 40.0 + p_iron * c.housing_to_ambient_K_W, 0.01);
  EXPECT_NEAR(obs.estimate().winding_C, 40.0 + p_iron * c.housing_to_ambient_K_W, 0.01);
  EXPECT_EQ(obs.estimate().loss_error_W, 0.0);
  EXPECT_NEAR(obs.estimate().time_since_measurement_s, 52000.0, 1e-6);
}

TEST(ThermalObserver, PredictionWithTemperatureDependentCopperLoss) {
  ThermalModelConfig c;
  Calibration cal;
  ThermalObserver obs(c, cal, 30.0);
  const double i2 = 2000.0;  // mean id^2 + iq^2
  EXPECT_NEAR(obs.copper_loss_W(i2), 1.5 * i2 * 0.133 * (1.0 + kAlpha * 5.0), 1e-9);
  Eigen::Matrix2d a;
  Eigen::Vector2d b;
  linear_system(network_of(c, cal), i2, 0.0, 30.0, a, b);
  const double dt = 0.2;
  for (int k = 0; k < 10000; ++k) {
    obs.predict(dt, i2, 0.0, 30.0);
  }
  const Eigen::Vector2d x = analytic(a, b, Eigen::Vector2d(30.0, 30.0), 2000.0);
  EXPECT_NEAR(obs.estimate().winding_C, x(0), 0.02);
  EXPECT_NEAR(obs.estimate().housing_C, x(1), 0.02);
}

// A motor cable (ThermalModelConfig::cable_resistance_20C_ohm) is part of what the drive
// measures, Rs0 at T0 included, at the ambient's temperature: Eq. 1 takes the winding's share
// alone, and so does the copper loss. Figures of round 8's agitator: 0.320 ohm of winding and
// 0.073 of cable at 35 C.
TEST(ThermalObserver, AMotorCableIsMeasuredButNeitherWarmsNorHeats) {
  const double rw0 = 0.320;
  const double t0 = 35.0;
  const double cable_20 = 0.073 * (234.5 + 20.0) / (234.5 + t0);  // 0.073 ohm at 35 C
  ThermalModelConfig c;
  c.cable_resistance_20C_ohm = cable_20;
  Calibration cal;
  cal.rs0_ohm = rw0 + 0.073;
  cal.t0_C = t0;
  ThermalObserver obs(c, cal, t0);
  EXPECT_NEAR(obs.winding_rs0_ohm(), rw0, 1e-12);
  EXPECT_NEAR(obs.cable_resistance_now_ohm(), 0.073, 1e-12);  // before any ambient: at T0
  // The winding at 85 C, the cable at the ambient of 35 C.
  const double measured = resistance_at_temperature_ohm(rw0, t0, 85.0) + 0.073;
  EXPECT_NEAR(obs.temperature_from_resistance_C(measured), 85.0, 1e-9);
  EXPECT_NEAR(obs.resistance_at_C(85.0), measured, 1e-12);
  // Without the key the whole rise is scaled by the winding's share of Rs0: 81 % of it.
  ThermalObserver no_cable(ThermalModelConfig{}, cal, t0);
  EXPECT_NEAR(no_cable.temperature_from_resistance_C(measured) - t0, 50.0 * rw0 / (rw0 + 0.073), 1e-9);
  // The copper loss is the winding's: at the estimate's temperature (T0 here).
  EXPECT_NEAR(obs.copper_loss_W(100.0), 1.5 * 100.0 * rw0, 1e-12);
  // The cable follows the ambient of the last prediction (copper, from its 20 C value).
  obs.predict(1e-3, 0.0, 0.0, 15.0);
  EXPECT_NEAR(obs.cable_resistance_now_ohm(), cable_20 * (234.5 + 15.0) / (234.5 + 20.0), 1e-12);
  const double winding_C = obs.estimate().winding_C;
  EXPECT_NEAR(obs.temperature_from_resistance_C(resistance_at_temperature_ohm(rw0, t0, winding_C) +
                                                obs.cable_resistance_now_ohm()),
              winding_C, 1e-9);
}

// A calibration whose T0 is not the ambient (an operator gives a warm winding's temperature):
// its events, the winding at 60 C and the cable at the ambient's 25 C, are referred to Rs0 at
// T0 = 45 C with the cable at T0 too, as winding_rs0_ohm() takes it off; the filter then reads
// the same resistance as 60 C. Adding the cable back at the ambient instead left Rw0 short by
// Rc20 (T0 - Ta) / 254.5 and read high (2.2 C at 10 K apart on the agitator).
TEST(ThermalObserver, ACalibrationAwayFromTheAmbientStoresTheCableAtT0) {
  const double rw_25 = 0.320;
  const double cable_20 = 0.0717;
  const double measured = resistance_at_temperature_ohm(rw_25, 25.0, 60.0) + cable_resistance_at_C(cable_20, 25.0);
  Calibration cal;
  cal.t0_C = 45.0;
  cal.rs0_ohm = resistance_referred_to_C(measured, 60.0, 45.0, cable_resistance_at_C(cable_20, 25.0),
                                         cable_resistance_at_C(cable_20, 45.0));
  EXPECT_NEAR(cal.rs0_ohm, resistance_at_temperature_ohm(rw_25, 25.0, 45.0) + cable_resistance_at_C(cable_20, 45.0),
              1e-15);
  ThermalModelConfig c;
  c.cable_resistance_20C_ohm = cable_20;
  ThermalObserver obs(c, cal, 25.0);
  obs.predict(1e-3, 0.0, 0.0, 25.0);  // the ambient known: the cable at 25 C
  EXPECT_NEAR(obs.temperature_from_resistance_C(measured), 60.0, 1e-9);
  // Without a cable the referral is Eq. 1 itself.
  EXPECT_DOUBLE_EQ(resistance_referred_to_C(0.2, 60.0, 45.0, 0.0, 0.0), 0.2 * resistance_at_temperature_ohm(1.0, 60.0, 45.0));
}

TEST(ThermalObserver, TimeScaleRunsThermalTimeFaster) {
  ThermalModelConfig slow;
  ThermalModelConfig fast = slow;
  fast.time_scale = 50.0;
  ThermalObserver a(slow, Calibration{}, 25.0);
  ThermalObserver b(fast, Calibration{}, 25.0);
  for (int k = 0; k < 1000; ++k) {
    a.predict(0.5, 1500.0, 150.0, 25.0);
    b.predict(0.01, 1500.0, 150.0, 25.0);
  }
  EXPECT_NEAR(a.estimate().winding_C, b.estimate().winding_C, 1e-9);
  EXPECT_NEAR(a.estimate().winding_std_C, b.estimate().winding_std_C, 1e-9);
  EXPECT_NEAR(b.estimate().time_since_measurement_s, 10.0, 1e-9);  // controller seconds
}

TEST(ThermalObserver, ResistanceMeasurementUsesTheHandComputedKalmanGain) {
  ThermalModelConfig c;
  Calibration cal;  // 0.133 ohm at 25 C
  ThermalObserver obs(c, cal, 40.0);
  // Eq. 1 by hand: 0.1438 ohm is 25 + (0.1438 / 0.133 - 1) / 3.93e-3 C.
  const double rs = 0.1438;
  const double z = 25.0 + (rs / 0.133 - 1.0) / kAlpha;
  EXPECT_NEAR(obs.temperature_from_resistance_C(rs), z, 1e-9);
  EXPECT_NEAR(obs.resistance_at_C(z), rs, 1e-12);
  const double rs_std = 0.0005;
  const double r = std::pow(rs_std / (kAlpha * 0.133), 2) + std::pow(c.measurement_floor_std_C, 2);
  const double p0 = c.initial_std_C * c.initial_std_C;
  const double gain = p0 / (p0 + r);
  ASSERT_TRUE(obs.update_resistance(rs, rs_std));
  const ThermalEstimate e = obs.estimate();
  EXPECT_NEAR(e.winding_C, 40.0 + gain * (z - 40.0), 1e-9);
  EXPECT_NEAR(e.winding_std_C, std::sqrt(p0 * r / (p0 + r)), 1e-9);
  // The housing and the loss error are uncorrelated with the winding at start: unchanged.
  EXPECT_NEAR(e.housing_C, 40.0, 1e-12);
  EXPECT_NEAR(e.loss_error_W, 0.0, 1e-12);
  EXPECT_EQ(e.time_since_measurement_s, 0.0);
}

// A model error shared by consecutive measurements widens the band by the share the state
// carries, without changing the gain: the same measurements move the estimate alike.
TEST(ThermalObserver, ASharedErrorWidensTheBandButNotTheGain) {
  ThermalModelConfig c;
  ThermalObserver plain(c, Calibration{}, 40.0);
  ThermalObserver shared(c, Calibration{}, 40.0);
  const double rs = plain.resistance_at_C(45.0);
  const double systematic_ohm = 0.001;  // about 1.9 C on the Table I motor
  const double systematic_C = systematic_ohm / (kAlpha * 0.133);
  for (int k = 0; k < 200; ++k) {
    ASSERT_TRUE(plain.update_resistance(rs, 0.002));
    ASSERT_TRUE(shared.update_resistance(rs, 0.002, systematic_ohm));
    EXPECT_NEAR(shared.estimate().winding_C, plain.estimate().winding_C, 1e-12);
  }
  // Averaging took the independent part down; the shared part stays.
  EXPECT_LT(plain.estimate().winding_std_C, 0.5 * systematic_C);
  EXPECT_GT(shared.estimate().winding_std_C, 0.95 * systematic_C);
  // Independent measurements replace it by their share (each its gain).
  auto excess = [&] {
    const double a = shared.estimate().winding_std_C;
    const double b = plain.estimate().winding_std_C;
    return std::sqrt(std::max(a * a - b * b, 0.0));
  };
  const double before = excess();
  for (int k = 0; k < 200; ++k) {
    ASSERT_TRUE(plain.update_resistance(rs, 0.002));
    ASSERT_TRUE(shared.update_resistance(rs, 0.002));
  }
  EXPECT_LT(excess(), 0.7 * before);
}

// A share of the band that every measurement through Eq. 1 has in common (`share` of an
// observer): `obs` and `plain` fused the same measurements, so the estimates agree (the same gain)
// and the bands differ by `term` in quadrature; a stored state holds the band without the share
// (the measurements were averaged down), and a restore adds it once, not twice. Returns the
// share of the restored observer.
template <class Share>
double expect_a_shared_share(const ThermalObserver& obs, const ThermalObserver& plain, double term,
                             ThermalObserver restored, ThermalObserver restored_plain, double ambient_C, Share share) {
  const ThermalEstimate e = obs.estimate();
  const ThermalEstimate p = plain.estimate();
  EXPECT_NEAR(e.winding_C, p.winding_C, 1e-12);
  EXPECT_NEAR(share(obs), term, 1e-9);
  EXPECT_NEAR(e.winding_std_C, std::hypot(p.winding_std_C, term), 1e-9);
  EXPECT_LT(p.winding_std_C, 1.0);
  EXPECT_NEAR(obs.state().winding_std_C, p.winding_std_C, 1e-9);
  restored.restore(obs.state(), 0.0, ambient_C);
  restored_plain.restore(plain.state(), 0.0, ambient_C);
  EXPECT_NEAR(restored.estimate().winding_std_C, std::hypot(restored_plain.estimate().winding_std_C, share(restored)), 1e-9);
  return share(restored);
}

// An Rs0 no calibration measured (the nameplate's) puts the same error into every measurement
// through Eq. 1, so averaging cannot take it out of the band: its share, dT/dRs0 times its
// uncertainty, (K + T) rs0_std_fraction for copper, stays in the band from the first fused
// measurement until a calibration replaces the Rs0. Before any measurement the model's
// temperatures do not rest on Rs0. Without it, a drive whose calibration timed out under load
// read 6 C low on a nameplate Rs0 3 % high with the truth outside its band half of the time
// (docs/estimator.md section 6, "An uncalibrated Rs0").
TEST(ThermalObserver, AnUncalibratedRs0StaysInTheBand) {
  ThermalModelConfig c;
  Calibration nameplate;  // 0.133 ohm at 25 C, not calibrated
  nameplate.rs0_std_fraction = kNameplateRs0StdFraction;
  Calibration exact = nameplate;
  exact.rs0_std_fraction = 0.0;
  ThermalObserver obs(c, nameplate, 40.0);
  ThermalObserver plain(c, exact, 40.0);
  EXPECT_EQ(obs.uncalibrated_rs0_std_C(), 0.0);
  EXPECT_NEAR(obs.estimate().winding_std_C, plain.estimate().winding_std_C, 1e-12);
  const double rs = obs.resistance_at_C(45.0);
  for (int k = 0; k < 400; ++k) {
    ASSERT_TRUE(obs.update_resistance(rs, 0.0005));
    ASSERT_TRUE(plain.update_resistance(rs, 0.0005));
  }
  const double term = (c.conductor_inferred_zero_C + obs.estimate().winding_C) * kNameplateRs0StdFraction;
  EXPECT_NEAR(term, 14.0, 0.1);  // at 45 C: (234.5 + 45) x 5 %
  const double restored_term =
      expect_a_shared_share(obs, plain, term, ThermalObserver(c, nameplate, 25.0), ThermalObserver(c, exact, 25.0), 25.0,
                            [](const ThermalObserver& o) { return o.uncalibrated_rs0_std_C(); });
  EXPECT_NEAR(restored_term, term, 1e-6);
  const ThermalEstimate p = plain.estimate();
  // A calibration replaces it.
  Calibration measured = exact;
  measured.calibrated = true;
  measured.rs0_std_fraction = kNameplateRs0StdFraction;  // ignored once calibrated
  obs.set_calibration(measured);
  EXPECT_EQ(obs.uncalibrated_rs0_std_C(), 0.0);
  EXPECT_NEAR(obs.estimate().winding_std_C, p.winding_std_C, 1e-9);
}

// The temperature a calibration refers Rs0 to comes from a sensor (or an operator): an error of
// T0 moves every estimate through Eq. 1 by dT/dT0 = (K + T) / (K + T0), the same in every
// measurement, so averaging cannot take it out of the band. Its share, the configured
// uncertainty times that ratio, is in the band once a calibration run's Rs0 is in use, and
// not in the filter's P (a stored state holds the band without it: no double count). An Rs0 no
// calibration measured is the nameplate's at its own reference: no T0 share.
TEST(ThermalObserver, TheCalibrationsTemperatureUncertaintyStaysInTheBand) {
  ThermalModelConfig plain_config;
  ThermalModelConfig c = plain_config;
  c.reference_std_C = 1.0;  // an NTC of +-2 C at two sigma
  Calibration cal;
  cal.rs0_ohm = 0.160;  // measured at 45 C
  cal.t0_C = 45.0;
  cal.calibrated = true;
  ThermalObserver obs(c, cal, 45.0);
  ThermalObserver plain(plain_config, cal, 45.0);
  EXPECT_NEAR(obs.reference_std_C(), 1.0, 1e-12);  // at T0 the ratio is 1
  const double rs = obs.resistance_at_C(52.0);
  for (int k = 0; k < 400; ++k) {
    ASSERT_TRUE(obs.update_resistance(rs, 0.0005));
    ASSERT_TRUE(plain.update_resistance(rs, 0.0005));
  }
  const double k = c.conductor_inferred_zero_C;
  const double term = (k + obs.estimate().winding_C) / (k + 45.0);
  EXPECT_NEAR(term, 1.025, 0.002);  // about 52 C on a calibration at 45 C
  expect_a_shared_share(obs, plain, term, ThermalObserver(c, cal, 45.0), ThermalObserver(plain_config, cal, 45.0), 45.0,
                        [](const ThermalObserver& o) { return o.reference_std_C(); });
  // The nameplate's Rs0 (no calibration run): its own share, rs0_std_fraction's, not T0's.
  Calibration nameplate;
  ThermalObserver uncalibrated(c, nameplate, 45.0);
  for (int j = 0; j < 10; ++j) {
    ASSERT_TRUE(uncalibrated.update_resistance(uncalibrated.resistance_at_C(52.0), 0.0005));
  }
  EXPECT_EQ(uncalibrated.reference_std_C(), 0.0);
  // A T0 that includes the thermal model's rise (a calibration on the nameplate after the drive's
  // own losses) carries that rise's uncertainty beside the sensor's, in quadrature; alone too.
  Calibration warm = cal;
  warm.t0_rise_std_C = 0.75;
  EXPECT_NEAR(ThermalObserver(c, warm, 45.0).reference_std_C(), 1.25, 1e-12);
  EXPECT_NEAR(ThermalObserver(plain_config, warm, 45.0).reference_std_C(), 0.75, 1e-12);
}

TEST(ThermalObserver, AfterPredictionAMeasurementAlsoMovesTheCorrelatedStates) {
  ThermalModelConfig c;
  ThermalObserver obs(c, Calibration{}, 40.0);
  for (int k = 0; k < 600; ++k) obs.predict(0.1, 1000.0, 100.0, 40.0);
  const ThermalEstimate before = obs.estimate();
  const double rs = obs.resistance_at_C(before.winding_C + 4.0);  // 4 C hotter than predicted
  ASSERT_TRUE(obs.update_resistance(rs, 0.0002));
  const ThermalEstimate after = obs.estimate();
  const double dw = after.winding_C - before.winding_C;
  EXPECT_GT(dw, 0.0);
  EXPECT_LT(dw, 4.0);
  // The loss-error state learns that the winding runs hotter than the model says.
  EXPECT_GT(after.loss_error_W, before.loss_error_W);
  // The housing is positively correlated with the winding: it moves the same way, less.
  const double dh = after.housing_C - before.housing_C;
  EXPECT_GT(dh, 0.0);
  EXPECT_LT(dh, dw);
  EXPECT_LT(after.winding_std_C, before.winding_std_C);
}

// A machine for the loss-model tests: the model's network, with a copper loss copper_scale
// times the model's and housing_loss_W on the housing that the model lacks, in 25 C ambient.
struct TestMachine {
  Network n;
  double copper_scale = 1.0;
  double housing_loss_W = 0.0;
  double tw = 25.0, th = 25.0;
  void step(double i2, double dt_s) {
    // Euler in 0.1 s steps: far below the network's time constants.
    for (int j = 0; j < static_cast<int>(std::lround(dt_s / 0.1)); ++j) {
      const double pcu = copper_scale * 1.5 * i2 * n.rs0 * (1.0 + kAlpha * (tw - n.t0));
      const double q = (tw - th) / n.rwh;
      tw += 0.1 * (pcu - q) / n.cw;
      th += 0.1 * (housing_loss_W + q - (th - 25.0) / n.rha) / n.ch;
    }
  }
  // 3000 s at i2, a measurement every 20 s.
  void learn(ThermalObserver& obs, double i2 = 1500.0) {
    for (int k = 1; k <= 3000; ++k) {
      step(i2, 1.0);
      obs.predict(1.0, i2, 0.0, 25.0);
      if (k % 20 == 0) {
        EXPECT_TRUE(obs.update_resistance(obs.resistance_at_C(tw), 0.0002));
      }
    }
  }
  // Then 1500 s at i2 with no measurement: the estimate's error at the end (its size).
  double unmeasured_error_C(ThermalObserver& obs, double i2 = 3000.0) {
    for (int k = 0; k < 1500; ++k) {
      step(i2, 1.0);
      obs.predict(1.0, i2, 0.0, 25.0);
    }
    return std::abs(obs.estimate().winding_C - tw);
  }
};

// The default filter with either loss state switched off (a prior and a random walk of 0).
ThermalModelConfig with_loss_states(bool watts, bool scale) {
  ThermalModelConfig c;
  if (!watts) {
    c.initial_loss_error_std_W = 0.0;
    c.loss_error_process_std_W_per_sqrt_s = 0.0;
  }
  if (!scale) {
    c.initial_loss_scale_std = 0.0;
    c.loss_scale_process_std_per_sqrt_s = 0.0;
  }
  return c;
}

// The machine of the loss-scale tests: 25 % more copper loss than the model computes.
TestMachine hotter_machine(const Network& n) { return TestMachine{n, 1.25, 0.0}; }

// A winding whose copper loss is 25 % above the model's (its capacity, thermal resistance or
// AC resistance as commissioned): measured during a spell at one load, the filter learns the
// loss's relative error k, and a following spell at twice the current's square without any
// measurement drifts far less than a filter that can learn only a missing loss in watts (the
// previous three-state filter: k's prior set to zero), whose watts learned at the first load are
// half of what the second needs.
TEST(ThermalObserver, ALossScaleLearnedAtOneLoadCarriesToAnother) {
  const Calibration cal;
  auto run = [&](bool learn_scale) {
    const ThermalModelConfig c = with_loss_states(true, learn_scale);
    ThermalObserver obs(c, cal, 25.0);
    TestMachine m = hotter_machine(network_of(c, cal));
    m.learn(obs);
    return m.unmeasured_error_C(obs);
  };
  const double watts_only = run(false);
  const double with_scale = run(true);
  // Measured: 15.4 C and 2.6 C (15.5 and 5.3 C while dP entered the winding node). At one load
  // a missing loss and a scaled one look alike, so the filter splits what it learns between
  // them by their priors (50 W, and 20 % of the copper loss, about 70 W here), and what dP took
  // does not double with the load; with dP on the housing it explains the winding's rise over
  // the housing less well, and k takes more of it.
  EXPECT_GT(watts_only, 10.0) << "the scenario no longer needs the loss's scale";
  EXPECT_LT(with_scale, 0.5 * watts_only);
}

// A loss the model lacks on the housing's side is learned there (dP enters the housing node):
// measured at light load, where the winding reads about the housing's temperature, it warms
// the housing without scaling the copper loss, so a following heavy spell without measurements
// keeps the winding's rise over the housing as the (right) copper loss gives it. A filter that
// can learn only the copper loss's scale puts the housing's 60 W into k and multiplies it by the
// heavy load's copper loss.
TEST(ThermalObserver, AHousingLossIsLearnedOnTheHousing) {
  const Calibration cal;
  struct Result {
    double error_C;
    double k;
    double missing_loss_W;
    double housing_error_C;  // at the end of the light load
  };
  auto run = [&](bool learn_watts) {
    const ThermalModelConfig c = with_loss_states(learn_watts, true);
    ThermalObserver obs(c, cal, 25.0);
    // 60 W on the housing, measured at light load, then ten times the current's square unmeasured.
    TestMachine m{network_of(c, cal), 1.0, 60.0};
    m.learn(obs, 300.0);
    const ThermalEstimate learned = obs.estimate();
    const double housing_error_C = learned.housing_C - m.th;
    const double error_C = m.unmeasured_error_C(obs, 3000.0);
    return Result{error_C, learned.loss_scale_error, learned.missing_loss_W, housing_error_C};
  };
  const Result housing = run(true);
  const Result scale_only = run(false);
  // Measured: dP 52.8 W and k 0.080 at the light load (at one load the two share what they
  // learn, by their priors), the housing 0.28 C cold, 7.0 C off after the heavy spell (k's share
  // scaled by the load); k alone: k 0.64 and 63.8 C off. A dP on the winding would give the same
  // winding temperature at the light load with 60 Rha / (Rha + Rwh) = 42 W and leave the
  // housing 2.3 C cold.
  EXPECT_GT(housing.missing_loss_W, 45.0);
  EXPECT_LT(std::abs(housing.housing_error_C), 1.0) << "the housing carries the loss";
  EXPECT_LT(std::abs(housing.error_C), 0.25 * std::abs(scale_only.error_C));
  EXPECT_LT(std::abs(housing.k), 0.5 * std::abs(scale_only.k)) << "the copper loss is the model's";
}

// What the filter learned of the loss model is the machine's: a restart from the stored state
// (a power cycle without downtime) keeps it, and the same unmeasured spell as above ends as
// close as without the restart; a state without it (an older file) restarts from the priors.
TEST(ThermalObserver, TheLearnedLossModelSurvivesARestart) {
  const ThermalModelConfig c;
  const Calibration cal;
  ThermalObserver before(c, cal, 25.0);
  TestMachine m = hotter_machine(network_of(c, cal));
  m.learn(before);
  const ThermalState stored = before.state();
  ASSERT_TRUE(stored.has_loss_errors);
  EXPECT_GT(stored.loss_scale_error, 0.1) << "the scenario teaches k";
  EXPECT_LT(stored.loss_scale_std, c.initial_loss_scale_std);

  ThermalObserver kept(c, cal, 25.0);
  kept.restore(stored, 0.0, 25.0);
  EXPECT_DOUBLE_EQ(kept.estimate().loss_scale_error, stored.loss_scale_error);
  EXPECT_DOUBLE_EQ(kept.estimate().missing_loss_W, stored.missing_loss_W);
  EXPECT_NEAR(kept.estimate().loss_scale_std, stored.loss_scale_std, 1e-12);
  EXPECT_NEAR(kept.state().loss_correlation, stored.loss_correlation, 1e-9) << "dP and k learned together";
  EXPECT_LT(stored.loss_correlation, -0.5) << "at one load a combination of dP and k Pcu is what is learned";
  ThermalState old_file = stored;
  old_file.has_loss_errors = false;
  ThermalObserver forgot(c, cal, 25.0);
  forgot.restore(old_file, 0.0, 25.0);
  EXPECT_EQ(forgot.estimate().loss_scale_error, 0.0);
  EXPECT_DOUBLE_EQ(forgot.estimate().loss_scale_std, c.initial_loss_scale_std);

  TestMachine m_kept = m;
  TestMachine m_forgot = m;
  const double error_kept = m_kept.unmeasured_error_C(kept);
  const double error_forgot = m_forgot.unmeasured_error_C(forgot);
  const double error_no_restart = m.unmeasured_error_C(before);
  // Measured: 2.55 C kept (the same as without the restart), 26.3 C from the priors (dP and k
  // both forgotten).
  EXPECT_NEAR(error_kept, error_no_restart, 0.2);
  EXPECT_LT(error_kept, 0.5 * error_forgot);


  // Over a downtime the loss errors grow by their random walks, never beyond the priors.
  ThermalObserver shortly(c, cal, 25.0);
  shortly.restore(stored, 100.0, 25.0);
  EXPECT_NEAR(shortly.estimate().loss_scale_std,
              std::sqrt(stored.loss_scale_std * stored.loss_scale_std +
                        c.loss_scale_process_std_per_sqrt_s * c.loss_scale_process_std_per_sqrt_s * 100.0),
              1e-12);
  ThermalObserver later(c, cal, 25.0);
  later.restore(stored, 1e7, 25.0);
  EXPECT_DOUBLE_EQ(later.estimate().loss_scale_std, c.initial_loss_scale_std);

  // A stored dP beyond five prior standard deviations is no error of this model (a file from
  // another machine): held at that bound. With k's learning switched off, k stays 0.
  ThermalState wild = stored;
  wild.missing_loss_W = 5e4;
  ThermalObserver bounded(c, cal, 25.0);
  bounded.restore(wild, 0.0, 25.0);
  EXPECT_DOUBLE_EQ(bounded.estimate().missing_loss_W, 5.0 * c.initial_loss_error_std_W);
  ThermalModelConfig no_k = c;
  no_k.initial_loss_scale_std = 0.0;
  no_k.loss_scale_process_std_per_sqrt_s = 0.0;
  ThermalObserver off(no_k, cal, 25.0);
  off.restore(stored, 0.0, 25.0);
  EXPECT_EQ(off.estimate().loss_scale_error, 0.0);
  EXPECT_EQ(off.estimate().loss_scale_std, 0.0);

  // A restart of the temperatures alone (a calibration) keeps what was learned.
  ThermalObserver recalibrated(c, cal, 25.0);
  recalibrated.keep_loss_errors(before);
  EXPECT_DOUBLE_EQ(recalibrated.estimate().loss_scale_error, before.estimate().loss_scale_error);
  EXPECT_DOUBLE_EQ(recalibrated.estimate().missing_loss_W, before.estimate().missing_loss_W);
}

// A cooling path better than the model's (an outrunner's bell, a flange bolted to its machine:
// here half as much again, g = 0.5) sheds heat in proportion to the housing's rise. A missing
// loss in watts learned at one temperature is too little at a hotter one; the cooling path's
// relative error g, learned as the housing warms (a light load, then a heavy one, both
// measured), carries over. Then a heavier spell without
// measurements ends closer with g than a filter without it (its prior set to zero), and a
// restart from the stored state keeps g; a state without it (an older file) restarts g from
// its prior.
TEST(ThermalObserver, ACoolingPathsErrorIsLearnedAndCarriesToAHotterSpell) {
  const Calibration cal;
  auto run = [&](bool learn_cooling, ThermalState* stored) {
    ThermalModelConfig c;
    if (!learn_cooling) {
      c.initial_cooling_scale_std = 0.0;
    }
    ThermalObserver obs(c, cal, 25.0);
    Network n = network_of(c, cal);
    n.rha /= 1.5;
    TestMachine m{n, 1.0, 0.0};
    m.learn(obs, 1500.0);
    m.learn(obs, 3000.0);
    if (stored != nullptr) {
      *stored = obs.state();
    }
    return m.unmeasured_error_C(obs, 5000.0);
  };
  ThermalState stored;
  const double with_g = run(true, &stored);
  const double without_g = run(false, nullptr);
  // Measured: 3.8 C with g (learned 0.22 +- 0.18: the winding alone is measured, and dP and k
  // take their shares by their priors), 6.9 C without (dP -58 W and k -0.12 at the end of the
  // heavy spell, too little for the hotter housing).
  EXPECT_GT(without_g, 4.0) << "the scenario no longer needs the cooling's error";
  EXPECT_LT(with_g, 0.7 * without_g);
  ASSERT_TRUE(stored.has_cooling_error);
  EXPECT_GT(stored.cooling_scale_error, 0.1) << "a better path is a positive g";
  EXPECT_LT(stored.cooling_scale_std, ThermalModelConfig{}.initial_cooling_scale_std);

  const ThermalModelConfig c;
  ThermalObserver kept(c, cal, 25.0);
  kept.restore(stored, 0.0, 25.0);
  EXPECT_DOUBLE_EQ(kept.state().cooling_scale_error, stored.cooling_scale_error);
  EXPECT_DOUBLE_EQ(kept.state().cooling_scale_std, stored.cooling_scale_std);
  EXPECT_DOUBLE_EQ(kept.estimate().cooling_scale_error, stored.cooling_scale_error);
  ThermalState old_file = stored;
  old_file.has_cooling_error = false;
  ThermalObserver forgot(c, cal, 25.0);
  forgot.restore(old_file, 0.0, 25.0);
  EXPECT_EQ(forgot.state().cooling_scale_error, 0.0);
  EXPECT_DOUBLE_EQ(forgot.state().cooling_scale_std, c.initial_cooling_scale_std);
  // A stored g beyond the filter's bounds (a cooling path between half and twice the model's)
  // is held at the bound; with g's learning off it stays 0.
  ThermalState wild = stored;
  wild.cooling_scale_error = 7.0;
  ThermalObserver bounded(c, cal, 25.0);
  bounded.restore(wild, 0.0, 25.0);
  EXPECT_DOUBLE_EQ(bounded.state().cooling_scale_error, 1.0);
  ThermalModelConfig no_g = c;
  no_g.initial_cooling_scale_std = 0.0;
  ThermalObserver off(no_g, cal, 25.0);
  off.restore(stored, 0.0, 25.0);
  EXPECT_EQ(off.state().cooling_scale_error, 0.0);
  EXPECT_EQ(off.state().cooling_scale_std, 0.0);
  EXPECT_FALSE(off.state().has_cooling_error) << "a g never learned is not stored (0 +- 0 would hold it at 0 for good)";
  // A downtime cools the stored state through the learned path: a better one cools it more.
  ThermalState warm = stored;
  warm.winding_C = 120.0;
  warm.housing_C = 100.0;
  ThermalState warm_model = warm;
  warm_model.cooling_scale_error = 0.0;
  ThermalObserver through_g(c, cal, 25.0);
  through_g.restore(warm, 2000.0, 25.0);
  ThermalObserver through_model(c, cal, 25.0);
  through_model.restore(warm_model, 2000.0, 25.0);
  EXPECT_LT(through_g.estimate().winding_C, through_model.estimate().winding_C - 1.0);
  EXPECT_GT(through_g.estimate().winding_C, 25.0);
  // A calibration's restart of the temperatures keeps it, as it keeps dP and k.
  ThermalObserver recalibrated(c, cal, 25.0);
  recalibrated.keep_loss_errors(kept);
  EXPECT_DOUBLE_EQ(recalibrated.state().cooling_scale_error, stored.cooling_scale_error);
}

// k stays physical (the machine's copper loss between half and twice the model's) however far
// the measurements pull, and an idle motor (no copper loss, so nothing shows k) does not make
// k less certain than its prior.
TEST(ThermalObserver, TheLossScaleStaysPhysicalAndWithinItsPrior) {
  ThermalModelConfig c;
  c.initial_cooling_scale_std = 0.0;  // k alone (a hotter winding also reads as a weaker cooling path)
  const Calibration cal;
  ThermalObserver obs(c, cal, 25.0);
  const Network n = network_of(c, cal);
  double tw = 25.0, th = 25.0;
  for (int k = 1; k <= 3000; ++k) {  // a winding with three times the model's copper loss
    for (int j = 0; j < 10; ++j) {
      const double pcu = 3.0 * 1.5 * 1500.0 * n.rs0 * (1.0 + kAlpha * (tw - n.t0));
      const double q = (tw - th) / n.rwh;
      tw += 0.1 * (pcu - q) / n.cw;
      th += 0.1 * (q - (th - 25.0) / n.rha) / n.ch;
    }
    obs.predict(1.0, 1500.0, 0.0, 25.0);
    if (k % 20 == 0) {
      (void)obs.update_resistance(obs.resistance_at_C(tw), 0.0002);
    }
  }
  EXPECT_LE(obs.estimate().loss_scale_error, 1.0);
  EXPECT_GE(obs.estimate().loss_scale_error, 0.9) << "the scale should have been pulled to its bound";
  for (int k = 0; k < 100000; ++k) {
    obs.predict(10.0, 0.0, 0.0, 25.0);  // 1e6 thermal seconds idle
  }
  EXPECT_LE(obs.estimate().loss_scale_std, c.initial_loss_scale_std * (1.0 + 1e-12));
  EXPECT_GT(obs.estimate().loss_scale_std, 0.5 * c.initial_loss_scale_std) << "nothing was observed: back near the prior";
}

// A measurement that belongs to a moment past (an event's pairs span a fraction of a second
// while the winding warms) is compared with the filter's estimate of that moment: a
// measurement that equals it exactly moves the state by nothing, where taken as of now it
// would pull the estimate back towards the past temperature by the gain times the warming.
TEST(ThermalObserver, AMeasurementIsComparedWithTheEstimateOfItsOwnTime) {
  ThermalModelConfig c;
  c.time_scale = 60.0;  // warming fast enough to matter over 0.3 s, as in the benchmarks
  Calibration cal;
  const double rs_std = 0.0002;
  auto warmed = [&]() {
    ThermalObserver obs(c, cal, 60.0);
    for (int k = 0; k < 100; ++k) {
      obs.predict(0.01, 60.0 * 60.0, 30.0, 25.0);  // 60 A: about 12 C per controller second
    }
    return obs;
  };
  ThermalObserver reference = warmed();
  const double now_C = reference.estimate().winding_C;
  // The rate the model predicts, and the estimate 0.3 s ago (30 updates of 10 ms).
  const double rate = reference.winding_rate_C_per_s();
  ASSERT_GT(rate, 5.0);
  ThermalObserver short_run(c, cal, 60.0);
  for (int k = 0; k < 70; ++k) {
    short_run.predict(0.01, 60.0 * 60.0, 30.0, 25.0);
  }
  const double past_C = short_run.estimate().winding_C;
  ASSERT_NEAR(now_C - past_C, 0.3 * rate, 0.1 * 0.3 * rate);  // the model's own warming

  ThermalObserver aged = warmed();
  ASSERT_TRUE(aged.update_resistance(aged.resistance_at_C(past_C), rs_std, 0.0, 0.3));
  EXPECT_NEAR(aged.estimate().winding_C, now_C, 1e-6);

  ThermalObserver as_of_now = warmed();
  ASSERT_TRUE(as_of_now.update_resistance(as_of_now.resistance_at_C(past_C), rs_std));
  EXPECT_LT(as_of_now.estimate().winding_C, now_C - 0.5 * (now_C - past_C));

  // Between two updates: the line between them (0.305 s: half-way from 70 to 69 updates back).
  ThermalObserver earlier(c, cal, 60.0);
  for (int k = 0; k < 69; ++k) {
    earlier.predict(0.01, 60.0 * 60.0, 30.0, 25.0);
  }
  const double between_C = 0.5 * (earlier.estimate().winding_C + short_run.estimate().winding_C);
  ThermalObserver halfway = warmed();
  ASSERT_TRUE(halfway.update_resistance(halfway.resistance_at_C(between_C), rs_std, 0.0, 0.305));
  EXPECT_NEAR(halfway.estimate().winding_C, now_C, 1e-6);

  // Older than the history kept (2.56 s): the oldest kept estimate stands in for it.
  ThermalObserver old = warmed();
  ThermalObserver first(c, cal, 60.0);
  first.predict(0.01, 60.0 * 60.0, 30.0, 25.0);
  ASSERT_TRUE(old.update_resistance(old.resistance_at_C(first.estimate().winding_C), rs_std, 0.0, 30.0));
  EXPECT_NEAR(old.estimate().winding_C, now_C, 1e-6);
}

// The look-back over a history that has wrapped (more updates than it keeps) and after a
// fusion, which moves the kept trajectory with the state.
TEST(ThermalObserver, TheLookBackWrapsAndMovesWithAFusion) {
  ThermalModelConfig c;
  c.time_scale = 60.0;
  Calibration cal;
  ThermalObserver obs(c, cal, 60.0);
  std::vector<double> after;  // the estimate after each update
  for (int k = 0; k < 300; ++k) {  // 3 s: the history (256 updates) has wrapped
    obs.predict(0.01, 60.0 * 60.0, 30.0, 25.0);
    after.push_back(obs.estimate().winding_C);
  }
  const double now_C = after.back();
  EXPECT_EQ(obs.winding_at_age_C(0.0), now_C);
  EXPECT_NEAR(obs.winding_at_age_C(0.10), after[299 - 10], 1e-9);
  EXPECT_NEAR(obs.winding_at_age_C(2.50), after[299 - 250], 1e-9);
  EXPECT_NEAR(obs.winding_at_age_C(1.005), 0.5 * (after[299 - 100] + after[299 - 101]), 1e-9);
  // Beyond the 256 kept: the oldest of them (255 updates back), not a stale slot.
  EXPECT_NEAR(obs.winding_at_age_C(2.60), after[299 - 255], 1e-9);
  EXPECT_NEAR(obs.winding_at_age_C(100.0), after[299 - 255], 1e-9);
  EXPECT_LT(after[299 - 255], now_C - 5.0);  // a warming run: the ages are told apart

  // A fusion moves the state, and the kept trajectory with it: a time before the fusion is
  // the old trajectory moved by the jump, so that the change since then is the model's.
  ASSERT_TRUE(obs.update_resistance(obs.resistance_at_C(now_C + 2.0), 0.0002));
  const double fused_C = obs.estimate().winding_C;
  const double jump_C = fused_C - now_C;
  ASSERT_GT(jump_C, 0.5);
  EXPECT_NEAR(obs.winding_at_age_C(0.5), after[299 - 50] + jump_C, 1e-9);
  obs.predict(0.01, 60.0 * 60.0, 30.0, 25.0);
  const double next_C = obs.estimate().winding_C;
  EXPECT_NEAR(obs.winding_at_age_C(0.005), 0.5 * (fused_C + next_C), 1e-9);
  EXPECT_NEAR(obs.winding_at_age_C(0.5), after[299 - 49] + jump_C, 1e-9);
}

// A measurement that extrapolates along a line through two earlier times (a field-weakening
// pair's Rs, EventEstimate::measured_from_s) is compared with the same line through the
// filter's trajectory: on a winding whose warming slows, the line lies above the trajectory,
// and that is no news.
TEST(ThermalObserver, AnExtrapolatedMeasurementIsComparedWithTheSameLine) {
  ThermalModelConfig c;
  c.time_scale = 60.0;
  Calibration cal;
  auto warmed = [&] {
    ThermalObserver obs(c, cal, 60.0);
    for (int k = 0; k < 200; ++k) {
      obs.predict(0.01, 60.0 * 60.0, 30.0, 25.0);
    }
    return obs;
  };
  ThermalObserver obs = warmed();
  const double now_C = obs.estimate().winding_C;
  // The line through the trajectory 1.2 s and 0.9 s ago, at now.
  const double a_C = obs.winding_at_age_C(1.2);
  const double b_C = obs.winding_at_age_C(0.9);
  const double line_C = a_C + (b_C - a_C) * 1.2 / 0.3;
  ASSERT_GT(line_C - now_C, 0.05);  // the warming slows: the line overshoots
  ASSERT_TRUE(obs.update_resistance(obs.resistance_at_C(line_C), 0.0002, 0.0, 0.0, 1.2, 0.9));
  EXPECT_NEAR(obs.estimate().winding_C, now_C, 1e-6);
  // Taken as of now, the same measurement pulls the state up by most of the overshoot.
  ThermalObserver plain = warmed();
  ASSERT_TRUE(plain.update_resistance(plain.resistance_at_C(line_C), 0.0002));
  EXPECT_GT(plain.estimate().winding_C - now_C, 0.5 * (line_C - now_C));
}

TEST(ThermalObserver, OutlierBeyondTheGateIsRejectedAndLeavesTheState) {
  ThermalModelConfig c;
  Calibration cal;
  const double rs_std = 0.001;
  const double r = std::pow(rs_std / (kAlpha * 0.133), 2) + std::pow(c.measurement_floor_std_C, 2);
  const double s = c.initial_std_C * c.initial_std_C + r;
  const double gate_C = c.gate_sigma * std::sqrt(s);
  auto rs_at = [&](double t) { return 0.133 * (1.0 + kAlpha * (t - 25.0)); };
  {
    ThermalObserver obs(c, cal, 50.0);
    obs.predict(1.0, 100.0, 50.0, 25.0);
    const ThermalEstimate before = obs.estimate();
    EXPECT_FALSE(obs.update_resistance(rs_at(before.winding_C + gate_C * 1.01), rs_std));
    EXPECT_FALSE(obs.update_resistance(rs_at(before.winding_C - gate_C * 1.01), rs_std));
    const ThermalEstimate after = obs.estimate();
    EXPECT_EQ(after.winding_C, before.winding_C);
    EXPECT_EQ(after.winding_std_C, before.winding_std_C);
    EXPECT_EQ(after.housing_C, before.housing_C);
    EXPECT_EQ(after.loss_error_W, before.loss_error_W);
    EXPECT_EQ(after.time_since_measurement_s, before.time_since_measurement_s);
    // Not-a-number resistances are rejected too.
    EXPECT_FALSE(obs.update_resistance(std::nan(""), rs_std));
    EXPECT_EQ(obs.estimate().winding_C, before.winding_C);
  }
  {
    // Just inside the gate: accepted. (The predict above changes P slightly; take a fresh one.)
    ThermalObserver obs(c, cal, 50.0);
    EXPECT_TRUE(obs.update_resistance(rs_at(50.0 + gate_C * 0.99), rs_std));
  }
}

// Huber's weight: inside huber_sigma a measurement is fused with its own variance; beyond it (and
// inside the gate) it moves the estimate exactly as far as one at huber_sigma would, and the
// band shrinks by less than a measurement at huber_sigma makes it shrink (its variance is
// scaled by |innovation| / (huber_sigma sigma)). At or above the gate the weight is off.
TEST(ThermalObserver, AFarMeasurementMovesTheEstimateNoFurtherThanOneAtHubersThreshold) {
  ThermalModelConfig c;
  Calibration cal;
  const double rs_std = 0.001;
  const double r = std::pow(rs_std / (kAlpha * 0.133), 2) + std::pow(c.measurement_floor_std_C, 2);
  const double p0 = c.initial_std_C * c.initial_std_C;
  const double s = p0 + r;
  auto rs_at = [&](double t) { return 0.133 * (1.0 + kAlpha * (t - 25.0)); };
  auto fused = [&](const ThermalModelConfig& config, double sigmas) {
    ThermalObserver obs(config, cal, 50.0);  // a known start: gated (and weighed) from its first
    EXPECT_TRUE(obs.update_resistance(rs_at(50.0 + sigmas * std::sqrt(s)), rs_std));
    return obs.estimate();
  };
  ASSERT_LT(c.huber_sigma, c.gate_sigma);
  const ThermalEstimate at_threshold = fused(c, c.huber_sigma);
  const ThermalEstimate inside = fused(c, 0.5 * c.huber_sigma);
  // Inside: the plain Kalman update.
  EXPECT_NEAR(inside.winding_C, 50.0 + p0 / s * 0.5 * c.huber_sigma * std::sqrt(s), 1e-9);
  EXPECT_NEAR(inside.winding_std_C, std::sqrt(p0 * r / s), 1e-9);
  EXPECT_NEAR(at_threshold.winding_C, 50.0 + p0 / s * c.huber_sigma * std::sqrt(s), 1e-9);
  for (const double sigmas : {1.2 * c.huber_sigma, 0.99 * c.gate_sigma}) {
    const ThermalEstimate far = fused(c, sigmas);
    EXPECT_NEAR(far.winding_C, at_threshold.winding_C, 1e-9) << sigmas << " sigma";
    // P - P^2 / s', s' = s |nu| / (huber sigma): the band shrinks, by less.
    const double s_far = s * sigmas / c.huber_sigma;
    EXPECT_NEAR(far.winding_std_C, std::sqrt(p0 - p0 * p0 / s_far), 1e-9) << sigmas << " sigma";
    EXPECT_GT(far.winding_std_C, at_threshold.winding_std_C);
    EXPECT_LT(far.winding_std_C, c.initial_std_C);
    // The correlated states move with the winding, as far as they would at the threshold.
    EXPECT_NEAR(far.housing_C, at_threshold.housing_C, 1e-9);
  }
  // Negative innovations alike.
  EXPECT_NEAR(fused(c, -1.5 * c.huber_sigma).winding_C, 50.0 - (at_threshold.winding_C - 50.0), 1e-9);
  // Off at or above the gate: the plain update however far inside the gate.
  ThermalModelConfig off = c;
  off.huber_sigma = off.gate_sigma;
  EXPECT_NEAR(fused(off, 0.99 * c.gate_sigma).winding_C, 50.0 + p0 / s * 0.99 * c.gate_sigma * std::sqrt(s), 1e-9);
  // The lowest threshold the configuration accepts (1 sigma) with a measurement just inside the
  // gate: a weight of 1/6, the covariance finite and the band shrunk by less than at 1 sigma.
  ThermalModelConfig low = c;
  low.huber_sigma = 1.0;
  const ThermalEstimate low_far = fused(low, 0.99 * c.gate_sigma);
  EXPECT_NEAR(low_far.winding_C, 50.0 + p0 / s * std::sqrt(s), 1e-9);
  EXPECT_NEAR(low_far.winding_std_C, std::sqrt(p0 - p0 * p0 / (s * 0.99 * c.gate_sigma)), 1e-9);
  EXPECT_TRUE(std::isfinite(low_far.loss_error_W));
  // A start without a known temperature takes its first measurement with its own variance,
  // however far from the guess (nothing trustworthy to weigh it against, as for the gate).
  const double u = c.unknown_initial_std_C * c.unknown_initial_std_C;
  const double s_unknown = u + r;
  const double far_C = 5.0 * c.huber_sigma * std::sqrt(s_unknown);
  ThermalObserver guess(c, cal, 50.0, false);
  ASSERT_TRUE(guess.update_resistance(rs_at(50.0 + far_C), rs_std));
  EXPECT_NEAR(guess.estimate().winding_C, 50.0 + u / s_unknown * far_C, 1e-9);
  EXPECT_NEAR(guess.estimate().winding_std_C, std::sqrt(u * r / s_unknown), 1e-9);
}

// Brute force: RK4 on the two-node network with the losses held constant, until the winding
// reaches the limit. Returns thermal seconds.
// `scale_with_housing` (if given) multiplies the constant loss p_cu by a function of how far
// the housing has warmed since the start.
double brute_force_time(const Network& n, double tw0, double th0, double p_cu, double p_fe, double ambient,
                        double limit, bool copper_follows_temperature, double i2,
                        const std::function<double(double)>& scale_with_housing = {}) {
  const double gwh = 1.0 / n.rwh;
  const double gha = 1.0 / n.rha;
  auto f = [&](const Eigen::Vector2d& x) {
    const double held = scale_with_housing ? p_cu * scale_with_housing(x(1) - th0) : p_cu;
    const double pcu = copper_follows_temperature ? 1.5 * i2 * n.rs0 * (1.0 + kAlpha * (x(0) - n.t0)) : held;
    return Eigen::Vector2d((pcu - gwh * (x(0) - x(1))) / n.cw, (p_fe + gwh * (x(0) - x(1)) - gha * (x(1) - ambient)) / n.ch);
  };
  Eigen::Vector2d x(tw0, th0);
  const double h = 0.2;
  double t = 0.0;
  while (t < 1e6) {
    const Eigen::Vector2d k1 = f(x);
    const Eigen::Vector2d k2 = f(x + 0.5 * h * k1);
    const Eigen::Vector2d k3 = f(x + 0.5 * h * k2);
    const Eigen::Vector2d k4 = f(x + h * k3);
    const Eigen::Vector2d next = x + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
    if (next(0) >= limit) {
      return t + h * (limit - x(0)) / (next(0) - x(0));
    }
    x = next;
    t += h;
  }
  return -1.0;
}

TEST(ThermalObserver, TimeToLimitMatchesABruteForceSimulation) {
  ThermalModelConfig c;
  Calibration cal;
  ThermalObserver obs(c, cal, 25.0);
  for (int k = 0; k < 600; ++k) obs.predict(0.5, 1500.0, 100.0, 25.0);  // warm up, housing lags
  // A measurement 3 C hotter than predicted teaches both loss errors.
  ASSERT_TRUE(obs.update_resistance(obs.resistance_at_C(obs.estimate().winding_C + 3.0), 0.0005));
  const ThermalEstimate e = obs.estimate();
  ASSERT_GT(e.missing_loss_W, 1.0);
  ASSERT_GT(e.loss_scale_error, 0.005);
  const double i2 = 3000.0, w = 100.0, ambient = 25.0, limit = 155.0;
  double t_out = -1.0;
  ASSERT_TRUE(obs.time_to_limit_s(limit, i2, w, ambient, &t_out));
  // As documented: the copper loss at the limit temperature scaled by (1 + k) in the winding,
  // dP with the iron loss in the housing, and the path to the ambient at the learned (1 + g)
  // times the model's conductance.
  const double p_cu = 1.5 * i2 * 0.133 * (1.0 + kAlpha * (limit - 25.0)) * (1.0 + e.loss_scale_error);
  const double p_fe = c.iron_loss_k1_W_s_rad * w + c.iron_loss_k2_W_s2_rad2 * w * w + e.missing_loss_W;
  Network n = network_of(c, cal);
  n.rha /= 1.0 + e.cooling_scale_error;
  const double expected = brute_force_time(n, e.winding_C, e.housing_C, p_cu, p_fe, ambient, limit, false, i2);
  ASSERT_GT(expected, 0.0);
  EXPECT_NEAR(t_out, expected, 0.5) << "expected " << expected;
  // Conservative: with the copper loss following the temperature it takes longer.
  const double realistic = brute_force_time(n, e.winding_C, e.housing_C, 0.0, p_fe, ambient, limit, true, i2);
  EXPECT_GT(realistic, t_out);
  // Controller seconds under thermal acceleration.
  ThermalModelConfig fast = c;
  fast.time_scale = 20.0;
  ThermalObserver obs_fast(fast, cal, 25.0);
  double t_fast = -1.0;
  double t_slow = -1.0;
  ThermalObserver obs_slow(c, cal, 25.0);
  ASSERT_TRUE(obs_fast.time_to_limit_s(limit, i2, w, ambient, &t_fast));
  ASSERT_TRUE(obs_slow.time_to_limit_s(limit, i2, w, ambient, &t_slow));
  EXPECT_NEAR(t_fast, t_slow / 20.0, 1e-6 * t_slow);
}

// At a held torque the current rises as the magnets' flux falls: the copper loss grows with the
// housing's temperature, linearised in the closed form (gamma W per K of housing).
TEST(ThermalObserver, TimeToLimitWithTheCurrentRisingAsTheMagnetsWarm) {
  ThermalModelConfig c;
  Calibration cal;
  ThermalObserver obs(c, cal, 25.0);
  for (int k = 0; k < 300; ++k) obs.predict(0.5, 2500.0, 100.0, 25.0);  // warm up, housing lags
  const ThermalEstimate e = obs.estimate();
  const double i2 = 2500.0, w = 100.0, ambient = 25.0, limit = 155.0;
  const double beta = -0.0012;  // NdFeB
  const double flux = 1.0 + beta * (e.housing_C - cal.t0_C);
  const double g = -2.0 * beta / flux;
  double held = -1.0;
  double rising = -1.0;
  ASSERT_TRUE(obs.time_to_limit_s(limit, i2, w, ambient, &held));
  ASSERT_TRUE(obs.time_to_limit_s(limit, i2, w, ambient, &rising, g));
  const double p_cu = 1.5 * i2 * 0.133 * (1.0 + kAlpha * (limit - 25.0));
  const double p_fe = c.iron_loss_k1_W_s_rad * w + c.iron_loss_k2_W_s2_rad2 * w * w;
  const Network n = network_of(c, cal);
  const double linear = brute_force_time(n, e.winding_C, e.housing_C, p_cu, p_fe, ambient, limit, false, i2,
                                         [&](double dh) { return 1.0 + g * dh; });
  ASSERT_GT(linear, 0.0);
  EXPECT_NEAR(rising, linear, 1e-3 * linear) << "the closed form solves the linearised network";
  // The flux's own law, i^2 ~ 1 / flux^2, grows faster than its tangent: the linearised time
  // lies a little late, by less than 5 % here (the housing warms by about 50 K on the way).
  const double exact = brute_force_time(n, e.winding_C, e.housing_C, p_cu, p_fe, ambient, limit, false, i2, [&](double dh) {
    const double f = (flux + beta * dh) / flux;
    return 1.0 / (f * f);
  });
  EXPECT_GE(rising, exact);
  EXPECT_LT(rising, 1.05 * exact);
  EXPECT_LT(rising, 0.9 * held) << "a rising current reaches the limit sooner";
  // A gain that would let the loss outgrow the housing's cooling is held at half of it: the
  // network keeps a steady state and the time stays a number.
  double runaway = -1.0;
  ASSERT_TRUE(obs.time_to_limit_s(limit, i2, w, ambient, &runaway, 1.0));
  EXPECT_TRUE(std::isfinite(runaway));
  EXPECT_GT(runaway, 0.0);
  EXPECT_LT(runaway, rising);
}

TEST(ThermalObserver, TimeToLimitWhenSafeOrAlreadyThere) {
  ThermalModelConfig c;
  Calibration cal;
  double t = -1.0;
  ThermalObserver cold(c, cal, 25.0);
  // 500 A^2: the steady state is far below 155 C.
  EXPECT_FALSE(cold.time_to_limit_s(155.0, 500.0, 50.0, 25.0, &t));
  ThermalObserver hot(c, cal, 160.0);
  ASSERT_TRUE(hot.time_to_limit_s(155.0, 0.0, 0.0, 25.0, &t));
  EXPECT_EQ(t, 0.0);
}

TEST(Derate, MonotoneBetweenTheConfiguredEnds) {
  DeratingConfig d;  // 80 A cold, 10 A at 155 C, from 130 C, on T + 2 sigma
  ThermalEstimate e;
  e.winding_std_C = 1.5;
  double previous = 1e9;
  for (double t = 20.0; t <= 200.0; t += 0.25) {
    e.winding_C = t;
    const DeratingResult r = derate(d, e);
    EXPECT_LE(r.current_limit_A, previous + 1e-12) << t;
    EXPECT_GE(r.current_limit_A, d.min_current_A);
    EXPECT_LE(r.current_limit_A, d.max_current_A);
    previous = r.current_limit_A;
    const double upper = t + 3.0;
    EXPECT_EQ(r.derating, upper > d.derate_start_C) << t;
  }
  e.winding_C = 127.0;  // upper bound exactly at the start
  EXPECT_EQ(derate(d, e).current_limit_A, 80.0);
  e.winding_C = 152.0;  // upper bound at the limit
  EXPECT_NEAR(derate(d, e).current_limit_A, 10.0, 1e-12);
  e.winding_C = 139.5;  // half way: (130 + 155) / 2 - 3
  EXPECT_NEAR(derate(d, e).current_limit_A, 45.0, 1e-12);
  e.winding_C = 190.0;
  EXPECT_NEAR(derate(d, e).current_limit_A, 10.0, 1e-12);
  // A temperature that is no number derates to the floor: never a NaN limit.
  e.winding_C = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(derate(d, e).current_limit_A, 10.0);
  EXPECT_TRUE(derate(d, e).derating);
}

TEST(Derate, TheMagnetsOnTheirOwnEnds) {
  DeratingConfig d;  // 80 A, 10 A at the magnets' 150 C, from 130 C, on the estimate itself
  EXPECT_EQ(derate_magnet(d, 130.0).current_limit_A, 80.0);
  EXPECT_FALSE(derate_magnet(d, 130.0).derating);
  EXPECT_NEAR(derate_magnet(d, 140.0).current_limit_A, 45.0, 1e-12);
  EXPECT_TRUE(derate_magnet(d, 140.0).derating);
  EXPECT_NEAR(derate_magnet(d, 150.0).current_limit_A, 10.0, 1e-12);
  EXPECT_NEAR(derate_magnet(d, 400.0).current_limit_A, 10.0, 1e-12);
  EXPECT_EQ(derate_magnet(d, std::numeric_limits<double>::infinity()).current_limit_A, 10.0);
  EXPECT_EQ(derate_magnet(d, std::numeric_limits<double>::quiet_NaN()).current_limit_A, 10.0);
  d.magnet_start_C = 60.0;  // an N grade's 80 C
  d.magnet_limit_C = 80.0;
  EXPECT_NEAR(derate_magnet(d, 75.0).current_limit_A, 27.5, 1e-12);
}


// A start without a known temperature (a warm motor after a power cycle): the first
// measurement is taken however far it is from the guess; from then on the gate applies.
TEST(ThermalObserver, AStartFromAGuessTakesItsFirstMeasurementUngated) {
  ThermalModelConfig c;
  ThermalObserver obs(c, Calibration{}, 25.0, false);
  EXPECT_NEAR(obs.estimate().winding_std_C, c.unknown_initial_std_C, 1e-9);
  EXPECT_FALSE(obs.anchored());
  const double rs_90 = obs.resistance_at_C(90.0);
  ASSERT_TRUE(obs.update_resistance(rs_90, 0.0002)) << "a warm motor is not an outlier";
  EXPECT_NEAR(obs.estimate().winding_C, 90.0, 1.0);
  EXPECT_TRUE(obs.anchored());
  EXPECT_FALSE(obs.update_resistance(obs.resistance_at_C(25.0), 0.0002)) << "now the gate applies";
  // A known start (a calibration at a soaked temperature) gates from the first measurement.
  ThermalObserver known(c, Calibration{}, 25.0);
  EXPECT_FALSE(known.update_resistance(known.resistance_at_C(90.0), 0.0002));
}

// An outlier that took the ungated first place does not hold the filter hostage: after a few
// correct measurements in a row are gated, the next one re-anchors it.
TEST(ThermalObserver, AWrongFirstMeasurementIsReplacedAfterRepeatedRejections) {
  ThermalModelConfig c;
  ThermalObserver obs(c, Calibration{}, 25.0, false);
  ASSERT_TRUE(obs.update_resistance(obs.resistance_at_C(200.0), 0.0002));  // the outlier
  const double rs_90 = obs.resistance_at_C(90.0);
  int gated = 0;
  while (!obs.update_resistance(rs_90, 0.0002) && gated < 20) {
    ++gated;
  }
  EXPECT_GE(gated, 1) << "the gate applies after the first measurement";
  EXPECT_LE(gated, 6) << "but not for ever";
  EXPECT_NEAR(obs.estimate().winding_C, 90.0, 2.0);
}

// Between measurements the band widens with the change the model predicts, through the copper
// loss's relative error k: k's column in the model is Pcu / Cw, so its prior (sigma 0.2) gives
// the winding at least 0.2 x the copper-driven part of the rise. A heat-up of about 130 C
// without a measurement, more than 80 % of it from the copper loss, ends at least 0.75 x that
// wide (1 sigma): the 0.75 leaves room for the variance cap on k (its covariance with the
// winding is scaled down with it) and for dP's share of the same rise.
// Measured at 25 C, then heated 4000 s at 3000 A^2 and 100 rad/s without a measurement: the
// band at the measurement and the rise.
struct UnmeasuredHeatUp {
  double start_std_C = 0.0;
  double rise_C = 0.0;
};
UnmeasuredHeatUp heat_up_unmeasured(ThermalObserver& obs) {
  EXPECT_TRUE(obs.update_resistance(obs.resistance_at_C(25.0), 0.0001));
  const double start_std_C = obs.estimate().winding_std_C;
  const double start_C = obs.estimate().winding_C;
  for (int k = 0; k < 4000; ++k) {
    obs.predict(1.0, 3000.0, 100.0, 25.0);
  }
  return {start_std_C, obs.estimate().winding_C - start_C};
}

TEST(ThermalObserver, TheBandGrowsWithThePredictedChangeBetweenMeasurements) {
  ThermalModelConfig c;
  ThermalObserver obs(c, Calibration{}, 25.0);
  const auto [start_std, rise] = heat_up_unmeasured(obs);
  ASSERT_GT(rise, 40.0);
  const double copper_share = obs.copper_loss_W(3000.0) / (obs.copper_loss_W(3000.0) + obs.iron_loss_W(100.0));
  ASSERT_GT(copper_share, 0.8);
  EXPECT_GE(obs.estimate().winding_std_C, 0.75 * c.initial_loss_scale_std * copper_share * rise);
  EXPECT_GT(obs.estimate().winding_std_C, start_std);
  ASSERT_TRUE(obs.update_resistance(obs.resistance_at_C(obs.estimate().winding_C + 5.0), 0.0001));
  EXPECT_LT(obs.estimate().winding_std_C, 1.0);
}

// The optional unlearned share (thermal.model_error_fraction): a heat-up without a measurement
// ends at least that fraction of its rise wide, and a measurement resets it.
TEST(ThermalObserver, TheModelErrorFractionWidensTheBandByThePredictedChange) {
  ThermalModelConfig c;
  c.model_error_fraction = 0.25;
  ThermalObserver obs(c, Calibration{}, 25.0);
  const auto [start_std, rise] = heat_up_unmeasured(obs);
  ASSERT_GT(rise, 40.0);
  EXPECT_GE(obs.estimate().winding_std_C, c.model_error_fraction * rise);
  EXPECT_GT(obs.estimate().winding_std_C, start_std);
  // A measurement takes the drift into the prediction's variance and resets it.
  ASSERT_TRUE(obs.update_resistance(obs.resistance_at_C(obs.estimate().winding_C + 5.0), 0.0001));
  EXPECT_LT(obs.estimate().winding_std_C, 1.0);
}

// A spell without measurements teaches the loss model at the next measurement: a winding with
// 25 % more copper loss than the model, heated 600 s at one load without a measurement, then
// measured once. Without an unlearned share of the band (the default) the measurement's
// innovation goes into k through its covariance with the winding; with a share of 25 % held
// apart from the loss states, most of it goes into the winding alone and k learns less than
// half as much (measured: k 0.23 and 0.10 of the true 0.25).
TEST(ThermalObserver, TheMeasurementAfterABlindSpellTeachesTheLossScale) {
  const Calibration cal;
  auto learned_k = [&](double fraction) {
    ThermalModelConfig c;
    c.model_error_fraction = fraction;
    ThermalObserver obs(c, cal, 25.0);
    TestMachine m = hotter_machine(network_of(c, cal));
    for (int k = 0; k < 600; ++k) {
      m.step(3000.0, 1.0);
      obs.predict(1.0, 3000.0, 0.0, 25.0);
    }
    EXPECT_TRUE(obs.update_resistance(obs.resistance_at_C(m.tw), 0.0002));
    return obs.estimate().loss_scale_error;
  };
  ASSERT_EQ(ThermalModelConfig{}.model_error_fraction, 0.0) << "the default under test";
  const double learned = learned_k(0.0);
  EXPECT_GT(learned, 0.15);
  EXPECT_LT(learned, 0.35);
  EXPECT_LT(learned_k(0.25), 0.6 * learned) << "the share held apart takes the innovation from k";
}

// A motor at rest (the drive disabled): no loss runs, so nothing teaches the loss states the
// cooling path's error, and the band grows by downtime_error_fraction of the cooling the model
// predicts, as over a downtime (restore()); a measurement resets it.
TEST(ThermalObserver, AtRestTheBandGrowsWithThePredictedCooling) {
  ThermalModelConfig c;
  ASSERT_GT(c.downtime_error_fraction, 0.2) << "the default under test";
  ThermalObserver obs(c, Calibration{}, 25.0);
  for (int k = 0; k < 3000; ++k) {
    obs.predict(1.0, 3000.0, 100.0, 25.0);
  }
  ASSERT_TRUE(obs.update_resistance(obs.resistance_at_C(obs.estimate().winding_C), 0.0001));
  const double hot_C = obs.estimate().winding_C;
  ASSERT_GT(hot_C, 100.0);
  for (int k = 0; k < 3000; ++k) {
    obs.predict(1.0, 0.0, 0.0, 25.0, true);
  }
  const double cooled = hot_C - obs.estimate().winding_C;
  ASSERT_GT(cooled, 40.0);
  EXPECT_GE(obs.estimate().winding_std_C, c.downtime_error_fraction * cooled);
  // The same cooling with the drive enabled at zero current (losses run, here none) does not
  // add it: the loss states' priors carry that band.
  ThermalObserver driven(c, Calibration{}, 25.0);
  for (int k = 0; k < 3000; ++k) {
    driven.predict(1.0, 3000.0, 100.0, 25.0);
  }
  ASSERT_TRUE(driven.update_resistance(driven.resistance_at_C(driven.estimate().winding_C), 0.0001));
  for (int k = 0; k < 3000; ++k) {
    driven.predict(1.0, 0.0, 0.0, 25.0);
  }
  EXPECT_LT(driven.estimate().winding_std_C, obs.estimate().winding_std_C);
  ASSERT_TRUE(obs.update_resistance(obs.resistance_at_C(obs.estimate().winding_C), 0.0001));
  EXPECT_LT(obs.estimate().winding_std_C, 1.0);
}

// A stored state cools through the downtime towards the ambient, as the model's network does.
TEST(ThermalObserver, AStoredStateIsCooledThroughTheDowntime) {
  ThermalModelConfig c;
  Calibration cal;
  Eigen::Matrix2d a;
  Eigen::Vector2d b;
  linear_system(network_of(c, cal), 0.0, 0.0, 20.0, a, b);
  ThermalObserver obs(c, cal, 25.0);
  const ThermalState stored{120.0, 90.0, 1.0};
  ASSERT_GT(c.downtime_error_fraction, 0.2) << "the default under test";
  for (const double downtime : {0.0, 300.0, 3000.0, 30000.0}) {
    obs.restore(stored, downtime, 20.0);
    const Eigen::Vector2d x = analytic(a, b, Eigen::Vector2d(120.0, 90.0), downtime);
    EXPECT_NEAR(obs.estimate().winding_C, x(0), 0.05) << downtime;
    EXPECT_NEAR(obs.estimate().housing_C, x(1), 0.05) << downtime;
    EXPECT_FALSE(obs.anchored());
    EXPECT_GE(obs.estimate().winding_std_C, 1.0);
    // The cooling path's error over the downtime widens the band (no loss runs to teach it).
    EXPECT_GE(obs.estimate().winding_std_C, c.downtime_error_fraction * (120.0 - x(0))) << downtime;
  }
  EXPECT_NEAR(obs.estimate().winding_C, 20.0, 1.0) << "long enough: at the ambient";
}

// A self-ventilated machine (thermal.fan_speed_rad_s): at a steady speed its model is the
// network whose housing-to-ambient path is the fan's share of the modelled one, at rest its
// natural convection's share; without a fan the share is exactly 1 (no figure of a machine
// without one moves).
TEST(ThermalObserver, AShaftFansCoolingFollowsTheSpeed) {
  ThermalModelConfig plain;
  EXPECT_EQ(housing_cooling_share(plain, 300.0), 1.0);
  ThermalModelConfig fan = plain;
  fan.fan_speed_rad_s = 300.0;
  fan.fan_standstill_share = 0.35;
  fan.fan_exponent = 0.8;
  EXPECT_DOUBLE_EQ(housing_cooling_share(fan, 0.0), 0.35);
  EXPECT_DOUBLE_EQ(housing_cooling_share(fan, -300.0), 1.0);
  Calibration cal;
  for (const double w : {0.0, 60.0, 300.0, 450.0}) {
    const double share = housing_cooling_share(fan, w);
    ThermalModelConfig equivalent = plain;
    equivalent.housing_to_ambient_K_W = plain.housing_to_ambient_K_W / share;
    ThermalObserver obs(fan, cal, 25.0);
    const double i2 = 30.0 * 30.0;
    const double p_iron = obs.iron_loss_W(w);
    Eigen::Matrix2d a;
    Eigen::Vector2d b;
    linear_system(network_of(equivalent, cal), i2, p_iron, 25.0, a, b);
    for (int k = 0; k < 6000; ++k) obs.predict(0.5, i2, w, 25.0);
    const Eigen::Vector2d x = analytic(a, b, Eigen::Vector2d(25.0, 25.0), 3000.0);
    EXPECT_NEAR(obs.estimate().winding_C, x(0), 0.02 * (x(0) - 25.0)) << w;
    EXPECT_NEAR(obs.estimate().housing_C, x(1), 0.02 * (x(1) - 25.0)) << w;
    // The time to a limit at this speed is the equivalent network's, from the same state.
    ThermalObserver same(equivalent, cal, 25.0);
    for (int k = 0; k < 6000; ++k) same.predict(0.5, i2, w, 25.0);
    double t_fan = -1.0;
    double t_same = -1.0;
    ASSERT_TRUE(obs.time_to_limit_s(obs.estimate().winding_C + 20.0, 2.0 * i2, w, 25.0, &t_fan)) << w;
    ASSERT_TRUE(same.time_to_limit_s(same.estimate().winding_C + 20.0, 2.0 * i2, w, 25.0, &t_same)) << w;
    EXPECT_NEAR(t_fan, t_same, 0.01 * t_same) << w;
    if (w < 300.0) {
      // The fan's share shows: the same load without the fan's model ends cooler.
      ThermalObserver without(plain, cal, 25.0);
      for (int k = 0; k < 6000; ++k) without.predict(0.5, i2, w, 25.0);
      EXPECT_GT(obs.estimate().housing_C - without.estimate().housing_C, 0.1 * (x(1) - 25.0)) << w;
    }
  }
  // A downtime cools a stopped fan's machine through natural convection alone.
  Eigen::Matrix2d a;
  Eigen::Vector2d b;
  ThermalModelConfig at_rest = plain;
  at_rest.housing_to_ambient_K_W = plain.housing_to_ambient_K_W / 0.35;
  linear_system(network_of(at_rest, cal), 0.0, 0.0, 20.0, a, b);
  ThermalObserver restored(fan, cal, 25.0);
  restored.restore(ThermalState{120.0, 90.0, 1.0}, 3000.0, 20.0);
  const Eigen::Vector2d x = analytic(a, b, Eigen::Vector2d(120.0, 90.0), 3000.0);
  EXPECT_NEAR(restored.estimate().winding_C, x(0), 0.05);
  EXPECT_NEAR(restored.estimate().housing_C, x(1), 0.05);
}

// The ambient moved in the downtime (stored at 5 C at night, 30 C at the restart): the truth lies
// between the network's relaxations towards the two ambients, whatever the ambient did between
// (it moved monotonically). The restored state takes their middle, and its 2 sigma reaches
// either end; before, it stayed on the stored ambient's cooling, 25 K low after a long night.
TEST(ThermalObserver, ARestoreReferredToAnotherAmbientLiesBetweenTheTwoCoolings) {
  ThermalModelConfig c;
  Calibration cal;
  const ThermalState stored{60.0, 50.0, 1.0};
  for (const double downtime : {300.0, 3000.0, 30000.0}) {
    Eigen::Matrix2d a;
    Eigen::Vector2d b;
    linear_system(network_of(c, cal), 0.0, 0.0, 5.0, a, b);
    const Eigen::Vector2d cold = analytic(a, b, Eigen::Vector2d(60.0, 50.0), downtime);
    linear_system(network_of(c, cal), 0.0, 0.0, 30.0, a, b);
    const Eigen::Vector2d warm = analytic(a, b, Eigen::Vector2d(60.0, 50.0), downtime);
    ThermalObserver obs(c, cal, 25.0);
    obs.restore(stored, downtime, 5.0);
    const double sigma_before = obs.estimate().winding_std_C;
    ASSERT_NEAR(obs.estimate().winding_C, cold(0), 0.05);
    const double shift = obs.refer_restored_to_ambient(30.0);
    EXPECT_NEAR(shift, 0.5 * (warm(0) - cold(0)), 0.05) << downtime;
    EXPECT_NEAR(obs.estimate().winding_C, 0.5 * (cold(0) + warm(0)), 0.05) << downtime;
    EXPECT_NEAR(obs.estimate().housing_C, 0.5 * (cold(1) + warm(1)), 0.05) << downtime;
    // 2 sigma reaches both ends: the stored state's band and half the span, in quadrature.
    const double half_span = 0.5 * (warm(0) - cold(0));
    EXPECT_NEAR(obs.estimate().winding_std_C, std::hypot(sigma_before, 0.5 * half_span), 0.02) << downtime;
    EXPECT_GE(2.0 * obs.estimate().winding_std_C, half_span) << downtime;
    EXPECT_EQ(obs.refer_restored_to_ambient(40.0), 0.0) << "once";
  }
  // Nothing to refer: the same ambient, or the filter ran on since the restore.
  ThermalObserver same(c, cal, 25.0);
  same.restore(stored, 3000.0, 20.0);
  const double w = same.estimate().winding_C;
  EXPECT_EQ(same.refer_restored_to_ambient(20.0), 0.0);
  EXPECT_EQ(same.estimate().winding_C, w);
  ThermalObserver ran(c, cal, 25.0);
  ran.restore(stored, 3000.0, 5.0);
  ran.predict(0.01, 0.0, 0.0, 5.0, true);
  EXPECT_EQ(ran.refer_restored_to_ambient(30.0), 0.0);
}

// A machine makes no cold. A missing loss learned negative (a cooling path better than the
// model's while the housing was warm, or estimates that read low) must not cool a motor below
// its coolant: it may take out at most the iron loss and once more what the modelled path to
// the ambient takes out, so it fades as the housing nears the ambient; where the iron loss
// covers it, dP holds in full.
TEST(ThermalObserver, ALearnedNegativeLossNeverCoolsTheMachineBelowItsAmbient) {
  const ThermalModelConfig c;
  const Calibration cal;
  ThermalState learned{30.0, 29.0, 1.0};
  learned.has_loss_errors = true;
  learned.missing_loss_W = -100.0;  // the state a helper found stored after DC-injection runs
  learned.missing_loss_std_W = 5.0;
  learned.loss_scale_std = 0.05;
  auto settle = [&](double speed_rad_s) {
    ThermalObserver obs(c, cal, 25.0);
    obs.restore(learned, 0.0, 25.0);
    for (int k = 0; k < 4000; ++k) {
      obs.predict(10.0, 0.0, speed_rad_s, 25.0, speed_rad_s == 0.0);  // 11 h, no current
    }
    return obs.estimate();
  };
  // At rest: no iron loss; the machine settles at its ambient (100 W out of a 0.125 K/W path
  // would have put it 12.5 C below).
  const ThermalEstimate rest = settle(0.0);
  EXPECT_NEAR(rest.winding_C, 25.0, 0.01);
  EXPECT_NEAR(rest.housing_C, 25.0, 0.01);
  EXPECT_DOUBLE_EQ(rest.missing_loss_W, -100.0) << "what was learned is kept for a faster spell";
  // At 100 rad/s the model's iron loss is 0.6 x 100 + 1e-3 x 100^2 = 70 W, less than dP takes:
  // the ambient again (21.25 C without the floor).
  EXPECT_NEAR(settle(100.0).housing_C, 25.0, 0.01);
  // At 150 rad/s it is 112.5 W: the housing gets 12.5 W, dP applies in full.
  EXPECT_NEAR(settle(150.0).housing_C, 25.0 + 12.5 * c.housing_to_ambient_K_W, 0.01);
  // On the way, at rest and 4 K above the ambient, the housing loses its path's heat twice
  // over (dP takes out once more what the path does), not 100 W, and not nothing (a floor at
  // Pfe + dP = 0 would take out only the path's): its first second against the network's rate.
  ThermalObserver obs(c, cal, 25.0);
  obs.restore(learned, 0.0, 25.0);
  obs.predict(1.0, 0.0, 0.0, 25.0, true);
  const double rate_C_per_s =
      ((30.0 - 29.0) / c.winding_to_housing_K_W - 2.0 * (29.0 - 25.0) / c.housing_to_ambient_K_W) / c.housing_capacity_J_K;
  EXPECT_NEAR(obs.estimate().housing_C - 29.0, rate_C_per_s, 0.01 * std::abs(rate_C_per_s));
}

// The model's rise (what the drive's own losses did, for a calibration on the ambient): from 0
// at a guess, driven by the losses alone (an ambient that moves is none of it), from a restored
// state's rise over the ambient, and never below 0 (a state stored colder than the ambient of the
// restart, or read low through a nameplate's Rs0, is no warmth the drive made).
TEST(ThermalObserver, TheModelsRiseIsTheDrivesOwnLosses) {
  ThermalModelConfig c;
  Calibration cal;
  ThermalObserver obs(c, cal, 25.0, false);
  EXPECT_EQ(obs.model_rise_C(), 0.0);
  for (int k = 0; k < 100; ++k) {
    obs.predict(0.01, 0.0, 0.0, 40.0);  // no loss, the ambient at 40 C
  }
  EXPECT_EQ(obs.model_rise_C(), 0.0) << "the ambient is no rise";
  for (int k = 0; k < 1000; ++k) {
    obs.predict(0.01, 30.0 * 30.0, 0.0, 40.0);  // 10 s at 30 A
  }
  // 10 s of 1.5 Rs i^2 into the winding's capacity, less what leaves it meanwhile.
  const double heating_K = 1.5 * cal.rs0_ohm * 900.0 * 10.0 / c.winding_capacity_J_K;
  EXPECT_GT(obs.model_rise_C(), 0.8 * heating_K);
  EXPECT_LT(obs.model_rise_C(), 1.2 * heating_K);
  ThermalState warm;
  warm.winding_C = 60.0;
  warm.housing_C = 50.0;
  warm.winding_std_C = 1.0;
  obs.restore(warm, 0.0, 25.0);
  EXPECT_NEAR(obs.model_rise_C(), 35.0, 1e-9);
  ThermalState cold = warm;
  cold.winding_C = 20.0;
  cold.housing_C = 20.0;
  obs.restore(cold, 0.0, 25.0);
  EXPECT_EQ(obs.model_rise_C(), 0.0);
}

// The bus slope's error (BusSlopeTerm): estimates under load hold Vx at a value referred to
// their bus by a slope whose error moves each one by its sensitivity, u / |iq| here (110 V from
// where Vx was learned, |iq| 40-90 A; drs/dVx is about -1 / |iq| for fixed-magnitude pulses).
// With the error a state, estimates at several loads tell it from the winding's temperature:
// the winding comes out right and the error near the truth. Passed as today's shared error bar
// instead (the slope's prior in the estimate's variance and its systematic part), the same
// estimates leave the winding several kelvin high, inside a band the prior widened.
TEST(ThermalObserver, TheBusSlopesErrorIsLearnedFromEstimatesAtSeveralLoads) {
  ThermalModelConfig c;
  const Calibration cal;
  ThermalObserver with(c, cal, 80.0);
  ThermalObserver without(c, cal, 80.0);
  const double r_true = with.resistance_at_C(80.0);
  constexpr double kPriorStd = 0.0016;  // 20 % of 0.8 us x 10 kHz
  constexpr double kTrueError = 0.002;  // the bridge's 1 us against the compensation's 0.8 us
  constexpr double kOwnStd_ohm = 0.0005;
  constexpr std::array<double, 4> kIq_A = {40.0, 90.0, 55.0, 75.0};
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, kOwnStd_ohm);
  for (int k = 0; k < 60; ++k) {
    const double sensitivity = 110.0 / kIq_A[static_cast<std::size_t>(k) % kIq_A.size()];
    const double rs = r_true + sensitivity * kTrueError + noise(rng);
    ASSERT_TRUE(with.update_resistance(rs, kOwnStd_ohm, 0.0, 0.0, 0.0, 0.0, {sensitivity, 0.0, kPriorStd * kPriorStd}));
    const double shared = sensitivity * kPriorStd;
    without.update_resistance(rs, std::hypot(kOwnStd_ohm, shared), shared);
  }
  const ThermalEstimate e = with.estimate();
  EXPECT_NEAR(e.winding_C, 80.0, 1.0);
  EXPECT_LT(std::abs(e.winding_C - 80.0), 2.0 * e.winding_std_C);
  EXPECT_NEAR(with.bus_slope_error(), kTrueError, 3.0 * with.bus_slope_error_std());
  EXPECT_LT(with.bus_slope_error_std(), 0.25 * kPriorStd);
  EXPECT_GT(without.estimate().winding_C - 80.0, 3.0) << "the case no longer shows the bias it is about";
  EXPECT_EQ(without.bus_slope_error(), 0.0);
  EXPECT_EQ(without.bus_slope_error_std(), 0.0);
}

// The state is the error of the slope the estimates are referred with. A slope the estimator
// moved without learning anything (its variance the same) only refers the state: the move comes
// out of it. One it learned from its own events (its variance fell from p_prev to p_new) is
// fused as the measurement of b those events make, y = r move / p_new with 1 / r = 1 / p_new -
// 1 / p_prev: the state combines the two by their precisions. A slope started afresh (its
// variance back at a prior) restarts the state; so does a calibration's restart, which does not
// carry it. Each step checked against the formula with a measurement that barely sees the slope
// (sensitivity 1e-9 ohm per V/V), at the filter's own winding and a kilo-ohm wide, so that it
// teaches nothing itself.
TEST(ThermalObserver, TheEstimatorsOwnSlopeLearningIsFusedAndAFreshSlopeRestartsTheState) {
  ThermalModelConfig c;
  ThermalObserver obs(c, Calibration{}, 60.0);
  const double rs = obs.resistance_at_C(60.0);
  constexpr double kVar = 0.0016 * 0.0016;
  for (int k = 0; k < 20; ++k) {
    const double sensitivity = k % 2 == 0 ? 2.0 : 1.0;
    ASSERT_TRUE(obs.update_resistance(rs + sensitivity * 0.002, 0.0005, 0.0, 0.0, 0.0, 0.0, {sensitivity, 0.0, kVar}));
  }
  const double learned = obs.bus_slope_error();
  const double learned_var = std::pow(obs.bus_slope_error_std(), 2);
  ASSERT_GT(learned, 0.001);
  ASSERT_LT(learned_var, 0.25 * kVar);
  constexpr double kTiny = 1e-9;
  auto quiet = [&](double slope, double var) {
    // At the filter's winding, with an error bar of a kilo-ohm: it teaches nothing.
    return obs.update_resistance(obs.resistance_at_C(obs.estimate().winding_C), 1000.0, 0.0, 0.0, 0.0, 0.0,
                                 {kTiny, slope, var});
  };
  // Moved, nothing learned: referred.
  const double small_move = 0.0001;
  ASSERT_TRUE(quiet(small_move, kVar));
  EXPECT_NEAR(obs.bus_slope_error(), learned - small_move, 1e-9);
  EXPECT_NEAR(std::pow(obs.bus_slope_error_std(), 2), learned_var, 1e-15);
  // Learned by the estimator: 0.0015 +- 0.0004 from its prior 0 +- 0.0016 (in the frame the
  // state started in), fused with the state's b = learned +- sqrt(learned_var).
  const double p_new = 0.0004 * 0.0004;
  const double r = p_new * kVar / (kVar - p_new);
  const double y = r * (0.0015 - small_move) / p_new + small_move;  // in the state's first frame
  const double fused_var = 1.0 / (1.0 / learned_var + 1.0 / r);
  const double fused = fused_var * (learned / learned_var + y / r);
  ASSERT_TRUE(quiet(0.0015, p_new));
  EXPECT_NEAR(obs.bus_slope_error(), fused - 0.0015, 1e-7);
  EXPECT_NEAR(std::pow(obs.bus_slope_error_std(), 2), fused_var, 1e-12);
  EXPECT_LT(fused_var, std::min(learned_var, p_new)) << "both taught b";
  // Started afresh (a calibration resets the slope to its prior): restarted.
  ASSERT_TRUE(quiet(0.0, kVar));
  EXPECT_NEAR(obs.bus_slope_error(), 0.0, 1e-9);
  EXPECT_NEAR(obs.bus_slope_error_std(), 0.0016, 1e-9);
  ThermalObserver calibrated(c, Calibration{}, 60.0);
  calibrated.keep_loss_errors(obs);
  EXPECT_EQ(calibrated.bus_slope_error(), 0.0);
  EXPECT_EQ(calibrated.bus_slope_error_std(), 0.0);
  ThermalObserver restored = obs;
  restored.restore(obs.state(), 10.0, 25.0);
  EXPECT_EQ(restored.bus_slope_error_std(), 0.0);
  // A measurement without the term leaves the state alone (it has no covariance with the rest
  // after the restart).
  ASSERT_TRUE(obs.update_resistance(rs + 0.001, 0.0005));
  EXPECT_NEAR(obs.bus_slope_error_std(), 0.0016, 1e-9);
}

}  // namespace
}  // namespace pmsm::core
