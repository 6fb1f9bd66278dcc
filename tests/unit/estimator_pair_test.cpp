// PairRecorder, solve_fit and solve_means_fit on synthetic recordings built from known
// parameters (Section X, Eqs. 33-44).
//
// Every sample is generated from the rotor-frame voltage model with the project's two extra
// terms, evaluated analytically at the sample's own angle:
//
//   vd = Rs id - w Lq iq + Ld did/dt + Vx Gd + kd(theta) wm
//   vq = Rs iq + w Ld id + Ke wm + Vx Gq + kq(theta) wm
//
// Recording 2 is taken dTheta later at angles that fall between recording 1's samples, so the
// recorder has to interpolate; the EMF harmonics kd, kq are evaluated at the true angle of
// each sample, so they cancel only if the recorder matches by angle correctly.
#include <Eigen/Dense>
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <functional>
#include <optional>
#include <random>
#include <vector>

#include "pmsm/core/pair_estimator.hpp"

namespace pmsm::core {
namespace {

constexpr double kPeriod = 1e-4;

struct Truth {
  double rs_ohm = 0.15;
  double vx_V = 2.0;
  double ld_H = 6.0e-3;
  double lq_H = 5.5e-3;
  double ke_V_s_per_rad = 0.9716;  // phase peak per mechanical rad/s
  int pole_pairs = 3;
  // EMF harmonics, V s/rad (multiplied by wm): a 6th electrical harmonic on each axis and a
  // first mechanical-order term (rotor eccentricity) on d.
  double kd6 = 0.05;
  double kq6 = 0.03;
  double kd_mech = 0.0;
};

// How the injected current and the dead-time pattern look within one recording.
struct Shape {
  double f_A = 25.0;
  double modulation = 0.3;       // id = level F (1 + m sin(phi)): varying, so Ld is identifiable
  double g_mean = 1.2;           // Gd = level (g_mean + g_ripple cos(6 theta))
  double g_ripple = 0.3;
  bool g_collinear = false;      // Gd = g_mean * id / F exactly (Vx not identifiable)
};

struct RecordingSpec {
  double theta0_rad = 0.0;       // electrical angle of the first sample
  double arc_origin_rad = 0.0;   // where the recording's arc starts (phi = theta - origin)
  double omega_e_rad_s = 300.0;
  double level = 1.0;            // +1, -1 or 0
  double iq_A = 0.0;             // motoring current
  double id_A = 0.0;
  int samples = 0;
  double t0_s = 0.0;
  double vd_noise_V = 0.0;
};

PeriodSample make_sample(const Truth& m, const Shape& sh, const RecordingSpec& r, int k, std::mt19937_64* rng) {
  PeriodSample s;
  s.time_s = r.t0_s + k * kPeriod;
  const double theta = r.theta0_rad + r.omega_e_rad_s * k * kPeriod;
  const double phi = theta - r.arc_origin_rad;
  const double w = r.omega_e_rad_s;
  const double wm = w / m.pole_pairs;
  s.theta_e_rad = theta;
  s.omega_e_rad_s = w;
  s.omega_m_rad_s = wm;
  // Under reverse rotation phi runs negative; the shape is a function of the arc travelled.
  const double arc = std::abs(phi);
  const double a = 1.0 + sh.modulation * std::sin(arc);
  const double da_dt = sh.modulation * std::cos(arc) * std::abs(w);
  s.i_A = {r.id_A + r.level * sh.f_A * a, r.iq_A};
  s.di_dt_A_s = {r.level * sh.f_A * da_dt, 0.0};
  if (sh.g_collinear) {
    s.dead_time_pattern = {sh.g_mean * s.i_A.d / sh.f_A, 0.0};
  } else {
    s.dead_time_pattern = {r.level * (sh.g_mean + sh.g_ripple * std::cos(6.0 * theta)),
                           r.level * 0.2 * std::sin(6.0 * theta)};
  }
  const double kd = m.kd6 * std::sin(6.0 * theta + 0.3) + m.kd_mech * std::sin(theta / m.pole_pairs + 0.7);
  const double kq = m.kq6 * std::cos(6.0 * theta + 1.1);
  s.v_V.d = m.rs_ohm * s.i_A.d - w * m.lq_H * s.i_A.q + m.ld_H * s.di_dt_A_s.d + m.vx_V * s.dead_time_pattern.d +
            kd * wm;
  s.v_V.q = m.rs_ohm * s.i_A.q + w * m.ld_H * s.i_A.d + m.ke_V_s_per_rad * wm + m.vx_V * s.dead_time_pattern.q +
            kq * wm;
  if (rng != nullptr && r.vd_noise_V > 0.0) {
    std::normal_distribution<double> noise(0.0, r.vd_noise_V);
    s.v_V.d += noise(*rng);
  }
  return s;
}

struct PairSpec {
  Truth truth{};
  Shape shape{};
  double omega1_rad_s = 300.0;
  double omega2_rad_s = 300.0;
  double level1 = 1.0;
  double level2 = -1.0;
  double iq1_A = 0.0;
  double iq2_A = 0.0;
  double dtheta_rad = kTwoPi * 3;   // 2 pi p
  double offset_samples = 0.37;     // recording 2 starts this fraction of a sample past origin 2
  double arc_rad = kTwoPi;          // recording length
  double lq_config_H = 5.5e-3;
  double ld_config_H = 5.5e-3;      // the commissioned Ld0, moved to the left of the fit
  double noise_V = 0.0;
  int filter_length = 8;
};

struct PairRun {
  PairRecorder recorder{1024};
  std::vector<PeriodSample> second;  // every sample given to add_second
  std::size_t first_count = 0;
};

// Records one pair through the recorder. Returns the recorder (by pointer, it is large).
// between_recordings, if given, sees the recorder once recording 2 has begun.
void run_pair(const PairSpec& p, PairRun& out, std::mt19937_64* rng = nullptr,
              const std::function<void(const PairRecorder&)>& between_recordings = {}) {
  PairFitConfig cfg;
  cfg.lq_H = p.lq_config_H;
  cfg.ld_H = p.ld_config_H;
  cfg.filter_length = p.filter_length;
  const double direction = p.omega1_rad_s >= 0.0 ? 1.0 : -1.0;
  out.recorder.start(cfg, MatchBy::kAngle, direction);
  RecordingSpec r1;
  r1.theta0_rad = 0.4;
  r1.arc_origin_rad = r1.theta0_rad;
  r1.omega_e_rad_s = p.omega1_rad_s;
  r1.level = p.level1;
  r1.iq_A = p.iq1_A;
  r1.samples = static_cast<int>(std::ceil(p.arc_rad / std::abs(p.omega1_rad_s * kPeriod))) + 1;
  r1.vd_noise_V = p.noise_V;
  for (int k = 0; k < r1.samples; ++k) {
    ASSERT_TRUE(out.recorder.add_first(make_sample(p.truth, p.shape, r1, k, rng)));
  }
  out.first_count = static_cast<std::size_t>(r1.samples);
  const double origin2 = out.recorder.first_origin() + p.dtheta_rad;
  out.recorder.begin_second(origin2);
  if (between_recordings) {
    between_recordings(out.recorder);
  }
  RecordingSpec r2 = r1;
  r2.arc_origin_rad = r1.theta0_rad + direction * p.dtheta_rad;
  r2.theta0_rad = r2.arc_origin_rad + direction * p.offset_samples * std::abs(p.omega2_rad_s) * kPeriod;
  r2.omega_e_rad_s = p.omega2_rad_s;
  r2.level = p.level2;
  r2.iq_A = p.iq2_A;
  r2.t0_s = 0.5;
  r2.samples = static_cast<int>(std::ceil(p.arc_rad / std::abs(p.omega2_rad_s * kPeriod))) + 3;
  for (int k = 0; k < r2.samples; ++k) {
    const PeriodSample s = make_sample(p.truth, p.shape, r2, k, rng);
    out.recorder.add_second(s);
    out.second.push_back(s);
  }
}

FitOptions options(bool fit_vx, bool fit_ld, double fixed_vx = 0.0) {
  FitOptions o;
  o.fit_vx = fit_vx;
  o.fit_ld = fit_ld;
  o.fixed_vx_V = fixed_vx;
  return o;
}

// The simulator copies a drive (the disturbance metric's twin) at any period, a pair's first
// recording included, and a copy carries only the samples recorded. A copy made between the two
// recordings, constructed or assigned over a recorder of another capacity or over one holding a
// recording of its own, matches recording 2 as the original does, to the last bit.
TEST(PairFit, ARecorderCopiedBetweenItsRecordingsCarriesOnAsTheOriginal) {
  PairSpec p;
  PairRun run;
  std::optional<PairRecorder> constructed;
  PairRecorder wider(2048);
  PairRun other;
  PairSpec q = p;
  q.level1 = 0.5;
  q.omega1_rad_s = 200.0;
  run_pair(q, other);  // a longer recording of its own, to be overwritten
  ASSERT_GT(other.first_count, 0U);
  run_pair(p, run, nullptr, [&](const PairRecorder& r) {
    constructed.emplace(r);
    wider = r;
    other.recorder = r;
  });
  for (PairRecorder* copy : {&*constructed, &wider, &other.recorder}) {
    EXPECT_EQ(copy->first_size(), run.first_count);
    for (const PeriodSample& s : run.second) {
      copy->add_second(s);
    }
    const BlockedSums& a = copy->sums();
    const BlockedSums& b = run.recorder.sums();
    EXPECT_EQ(std::memcmp(&a, &b, sizeof(BlockedSums)), 0);
    EXPECT_GT(b.total().n, 0.0);
  }
}

TEST(PairFit, RecoversRsVxAndLdFromABipolarPairWithoutHarmonics) {
  PairSpec p;
  p.truth.kd6 = 0.0;
  p.truth.kq6 = 0.0;
  PairRun run;
  run_pair(p, run);
  const FitResult fit = solve_fit(run.recorder.sums(), options(true, true));
  ASSERT_TRUE(fit.valid);
  // Every term of the model is linear in the samples, so even the interpolation is exact.
  EXPECT_NEAR(fit.rs_ohm, p.truth.rs_ohm, 1e-9);
  EXPECT_NEAR(fit.vx_V, p.truth.vx_V, 1e-7);
  // The fit's Ld is what the commissioned Ld0 misses: Ld - Ld0.
  EXPECT_NEAR(fit.ld_H, p.truth.ld_H - p.ld_config_H, 1e-10);
  EXPECT_LT(fit.residual_rms_V, 1e-5);  // the RSS comes from the normal equations: rounding
  // The bipolar difference holds twice the injected current: dId = 2 F (1 + m sin phi), whose
  // RMS over whole turns is 2 F sqrt(1 + m^2 / 2) (the first filter_length - 1 samples only
  // fill the moving average, hence the loose tolerance).
  EXPECT_NEAR(fit.signal_rms_A, 2.0 * 25.0 * std::sqrt(1.0 + 0.045), 0.5);
}

TEST(PairFit, CommissionedLdRemovesTheInductiveVoltageWithoutTheLdRegressor) {
  // The injection varies within the recording (d(dId/dt) != 0). With Ld0 equal to the true
  // Ld, Eq. 3's inductive term is taken out on the left and the fit needs no Ld regressor.
  PairSpec p;
  p.truth.kd6 = 0.0;
  p.ld_config_H = p.truth.ld_H;
  PairRun run;
  run_pair(p, run);
  const FitResult fit = solve_fit(run.recorder.sums(), options(false, false, p.truth.vx_V));
  ASSERT_TRUE(fit.valid);
  EXPECT_NEAR(fit.rs_ohm, p.truth.rs_ohm, 1e-9);
  // With Ld0 1 mH off and no Ld regressor, the inductive residue (4.5 V peak, in quadrature
  // with the injection's modulation) is left in the residual.
  PairSpec q = p;
  q.ld_config_H = p.truth.ld_H - 1e-3;
  PairRun off;
  run_pair(q, off);
  const FitResult biased = solve_fit(off.recorder.sums(), options(false, false, p.truth.vx_V));
  ASSERT_TRUE(biased.valid);
  EXPECT_GT(biased.residual_rms_V, 0.1);
}

TEST(PairFit, TheEmfHarmonicCancelsWhenMatchedByAngle) {
  PairSpec p;
  PairRun without_emf;
  {
    PairSpec q = p;
    q.truth.kd6 = 0.0;
    run_pair(q, without_emf);
  }
  for (double kd : {0.05, 0.2}) {  // 5 V and 20 V of 6th harmonic on the d-axis at 100 rad/s
    PairSpec q = p;
    q.truth.kd6 = kd;
    PairRun run;
    run_pair(q, run);
    const FitResult fit = solve_fit(run.recorder.sums(), options(true, true));
    ASSERT_TRUE(fit.valid);
    EXPECT_NEAR(fit.rs_ohm, p.truth.rs_ohm, 2e-4) << "kd " << kd;
    EXPECT_NEAR(fit.vx_V, p.truth.vx_V, 0.02) << "kd " << kd;
  }
  // Control: the same harmonic with dTheta a little off a whole number of turns does not
  // cancel, and the fit shows it (so the test above can fail).
  PairSpec off = p;
  off.truth.kd6 = 0.05;
  off.dtheta_rad = kTwoPi * 3 + 0.2;
  PairRun run_off;
  run_pair(off, run_off);
  const FitResult bad = solve_fit(run_off.recorder.sums(), options(false, true, p.truth.vx_V));
  ASSERT_TRUE(bad.valid);
  EXPECT_GT(bad.residual_rms_V, 0.5);
}

TEST(PairFit, MechanicalHarmonicsNeedDThetaOfTwoPiP) {
  PairSpec p;
  p.truth.kd6 = 0.0;
  p.truth.kd_mech = 0.1;  // 10 V at 100 rad/s, once per mechanical turn
  {
    PairSpec q = p;
    q.dtheta_rad = kTwoPi * q.truth.pole_pairs;
    PairRun run;
    run_pair(q, run);
    const FitResult fit = solve_fit(run.recorder.sums(), options(false, true, p.truth.vx_V));
    ASSERT_TRUE(fit.valid);
    EXPECT_NEAR(fit.rs_ohm, p.truth.rs_ohm, 1e-4);
  }
  {
    // 2 pi electrical: the mechanical-order term is a third of a turn out and leaks into Rs.
    PairSpec q = p;
    q.dtheta_rad = kTwoPi * 2;
    PairRun run;
    run_pair(q, run);
    const FitResult fit = solve_fit(run.recorder.sums(), options(false, true, p.truth.vx_V));
    ASSERT_TRUE(fit.valid);
    EXPECT_GT(std::abs(fit.rs_ohm - p.truth.rs_ohm), 5e-3);
  }
}

TEST(PairFit, ReverseRotationMatchesByTheDirectionSignedAngle) {
  PairSpec p;
  p.omega1_rad_s = -300.0;
  p.omega2_rad_s = -300.0;
  PairRun run;
  run_pair(p, run);
  EXPECT_GT(run.recorder.first_extent(), kTwoPi - 0.05);  // extent is positive going backwards
  const FitResult fit = solve_fit(run.recorder.sums(), options(true, true));
  ASSERT_TRUE(fit.valid);
  EXPECT_NEAR(fit.rs_ohm, p.truth.rs_ohm, 2e-4);
  EXPECT_NEAR(fit.vx_V, p.truth.vx_V, 0.02);
  EXPECT_NEAR(fit.ld_H, p.truth.ld_H - p.ld_config_H, 2e-5);
}

TEST(PairFit, UnipolarPairHoldsTheInjectionOnce) {
  // Eq. 37: recording 1 without injection, recording 2 with -F; the difference is +F.
  PairSpec p;
  p.level1 = 0.0;
  p.level2 = -1.0;
  p.iq1_A = 8.0;
  p.iq2_A = 8.0;
  PairRun run;
  run_pair(p, run);
  const FitResult fit = solve_fit(run.recorder.sums(), options(true, true));
  ASSERT_TRUE(fit.valid);
  EXPECT_NEAR(fit.rs_ohm, p.truth.rs_ohm, 3e-4);
  EXPECT_NEAR(fit.vx_V, p.truth.vx_V, 0.03);
  EXPECT_NEAR(fit.signal_rms_A, 25.0 * std::sqrt(1.0 + 0.045), 0.3);
}

TEST(PairFit, LqCorrectionRemovesAMotoringCurrentChange) {
  // iq moves from 10 A to 12 A between the recordings: w Lq d(iq) = 3.3 V on the d-axis.
  PairSpec p;
  p.truth.kd6 = 0.0;
  p.iq1_A = 10.0;
  p.iq2_A = 12.0;
  p.lq_config_H = p.truth.lq_H;
  PairRun run;
  run_pair(p, run);
  const FitResult fit = solve_fit(run.recorder.sums(), options(false, true, p.truth.vx_V));
  ASSERT_TRUE(fit.valid);
  EXPECT_NEAR(fit.rs_ohm, p.truth.rs_ohm, 1e-9);
  // Without the correction the 3.3 V sits in the fit: about 3.3 V / 50 A = 66 mOhm.
  PairSpec q = p;
  q.lq_config_H = 0.0;
  PairRun uncorrected;
  run_pair(q, uncorrected);
  const FitResult biased = solve_fit(uncorrected.recorder.sums(), options(false, true, p.truth.vx_V));
  ASSERT_TRUE(biased.valid);
  EXPECT_GT(std::abs(biased.rs_ohm - p.truth.rs_ohm), 0.03);
}

TEST(PairFit, ConditionsReportTheMeansOfEachRecording) {
  PairSpec p;
  p.omega1_rad_s = 300.0;
  p.omega2_rad_s = 306.0;  // 2 % faster in recording 2
  p.iq1_A = 10.0;
  p.iq2_A = 11.5;
  PairRun run;
  run_pair(p, run);
  const PairConditions c = run.recorder.conditions();
  EXPECT_NEAR(c.omega_e_mean_1_rad_s, 300.0, 1e-9);
  EXPECT_NEAR(c.omega_e_mean_2_rad_s, 306.0, 1e-9);
  EXPECT_NEAR(c.iq_mean_1_A, 10.0, 1e-9);
  EXPECT_NEAR(c.iq_mean_2_A, 11.5, 1e-9);
  EXPECT_NEAR(c.id_mean_1_A, 25.0 * (1.0 + 0.3 * 0.0), 0.3 * 25.0 * 0.1);  // mean of 1 + m sin over one turn
  EXPECT_FALSE(c.any_modulation_clipped);
  EXPECT_FALSE(c.any_voltage_limited);
  // Matched samples: those of recording 2 inside [0, extent] of recording 1.
  std::size_t inside = 0;
  const double origin2 = run.recorder.first_origin() + p.dtheta_rad;
  for (const PeriodSample& s : run.second) {
    const double phi = s.theta_e_rad - origin2;
    inside += (phi >= 0.0 && phi <= run.recorder.first_extent()) ? 1U : 0U;
  }
  EXPECT_EQ(c.samples, inside);
  // The q-axis means over both recordings at the matched angles, from the analytic model
  // evaluated at the angles of recording 2's samples.
  double vq = 0.0, iq = 0.0, wm = 0.0;
  double n = 0.0;
  for (const PeriodSample& s : run.second) {
    const double phi = s.theta_e_rad - origin2;
    if (phi < 0.0 || phi > run.recorder.first_extent()) continue;
    RecordingSpec r1;
    r1.theta0_rad = s.theta_e_rad - p.dtheta_rad;
    r1.arc_origin_rad = run.recorder.first_origin();
    r1.omega_e_rad_s = 300.0;
    r1.level = p.level1;
    r1.iq_A = p.iq1_A;
    const PeriodSample a = make_sample(p.truth, p.shape, r1, 0, nullptr);
    vq += 0.5 * (a.v_V.q + s.v_V.q);
    iq += 0.5 * (a.i_A.q + s.i_A.q);
    wm += 0.5 * (a.omega_m_rad_s + s.omega_m_rad_s);
    n += 1.0;
  }
  EXPECT_NEAR(c.vq_mean_V, vq / n, 1e-3);
  EXPECT_NEAR(c.iq_mean_A, iq / n, 1e-9);
  EXPECT_NEAR(c.omega_m_mean_rad_s, wm / n, 1e-9);
}

// A sample on the loop's voltage limit is reported; one the bridge clipped marks the pair for rejection.
TEST(PairFit, LimitedAndClippedSamplesAreReported) {
  PairSpec p;
  PairFitConfig cfg;
  RecordingSpec r;
  r.theta0_rad = 0.0;
  r.omega_e_rad_s = 300.0;
  auto record = [&](bool clip) {
    PairRecorder rec(512);
    rec.start(cfg, MatchBy::kAngle, 1.0);
    for (int k = 0; k < 220; ++k) {
      PeriodSample s = make_sample(p.truth, p.shape, r, k, nullptr);
      s.voltage_limited = (k == 100 || k == 101);
      s.modulation_clipped = clip && k == 101;
      rec.add_first(s);
    }
    return rec.conditions();
  };
  const PairConditions limited = record(false);
  EXPECT_TRUE(limited.any_voltage_limited);
  EXPECT_FALSE(limited.any_modulation_clipped);
  const PairConditions clipped = record(true);
  EXPECT_TRUE(clipped.any_voltage_limited);
  EXPECT_TRUE(clipped.any_modulation_clipped);
}

TEST(PairFit, CollinearRegressorsMakeVxUnidentifiable) {
  PairSpec p;
  p.truth.kd6 = 0.0;
  p.shape.g_collinear = true;  // Gd = 1.2 id / F: Vx looks exactly like a resistance
  p.shape.modulation = 0.0;
  PairRun run;
  run_pair(p, run);
  const FitResult joint = solve_fit(run.recorder.sums(), options(true, false));
  EXPECT_FALSE(joint.valid);
  EXPECT_LT(joint.vx_identifiability, 1e-9);
  // With Vx held, Rs absorbs the error of the assumed Vx at the rate drs_dvx = -1.2 / F.
  const double assumed = 0.5;
  const FitResult held = solve_fit(run.recorder.sums(), options(false, false, assumed));
  ASSERT_TRUE(held.valid);
  EXPECT_NEAR(held.drs_dvx, -1.2 / 25.0, 1e-12);
  EXPECT_NEAR(held.rs_ohm, p.truth.rs_ohm - held.drs_dvx * (p.truth.vx_V - assumed), 1e-9);
  EXPECT_DOUBLE_EQ(held.vx_V, assumed);
  EXPECT_EQ(held.var_vx, 0.0);
}

TEST(PairFit, TooFewSamplesIsInvalid) {
  PairRecorder rec(64);
  PairFitConfig cfg;
  rec.start(cfg, MatchBy::kAngle, 1.0);
  const FitResult fit = solve_fit(rec.sums(), options(true, true));
  EXPECT_FALSE(fit.valid);
  EXPECT_EQ(fit.samples, 0.0);
  // A full recorder refuses further samples rather than growing.
  PairSpec p;
  RecordingSpec r;
  for (int k = 0; k < 64; ++k) {
    EXPECT_TRUE(rec.add_first(make_sample(p.truth, p.shape, r, k, nullptr)));
  }
  EXPECT_FALSE(rec.add_first(make_sample(p.truth, p.shape, r, 64, nullptr)));
  EXPECT_EQ(rec.first_size(), 64U);
}

TEST(PairFit, TimeMatchedRecordingsAtStandstill) {
  // No rotation: matched by time. The injection varies in time, so dId and d(dId/dt) differ.
  Truth m;
  PairRecorder rec(2048);
  PairFitConfig cfg;
  cfg.lq_H = m.lq_H;
  cfg.ld_H = 5.0e-3;  // commissioned 1 mH low
  rec.start(cfg, MatchBy::kTime, 1.0);
  auto sample = [&](double t, double t_origin, double level) {
    PeriodSample s;
    s.time_s = t;
    s.theta_e_rad = 1.0;
    const double tau = t - t_origin;
    const double a = 1.0 + 0.3 * std::sin(kTwoPi * 20.0 * tau);
    const double da = 0.3 * kTwoPi * 20.0 * std::cos(kTwoPi * 20.0 * tau);
    s.i_A = {level * 20.0 * a, 0.0};
    s.di_dt_A_s = {level * 20.0 * da, 0.0};
    s.dead_time_pattern = {level * (1.1 + 0.2 * std::sin(kTwoPi * 33.0 * tau)), 0.0};
    s.v_V = {m.rs_ohm * s.i_A.d + m.ld_H * s.di_dt_A_s.d + m.vx_V * s.dead_time_pattern.d, 0.0};
    return s;
  };
  for (int k = 0; k < 500; ++k) {
    rec.add_first(sample(k * kPeriod, 0.0, 1.0));
  }
  EXPECT_NEAR(rec.first_extent(), 499 * kPeriod, 1e-12);
  const double origin2 = 0.2;
  rec.begin_second(origin2);
  for (int k = 0; k < 505; ++k) {
    const double t = origin2 + (k + 0.5) * kPeriod;  // half a period off recording 1's grid
    rec.add_second(sample(t, origin2, -1.0));
  }
  const FitResult fit = solve_fit(rec.sums(), options(true, true));
  ASSERT_TRUE(fit.valid);
  EXPECT_NEAR(fit.rs_ohm, m.rs_ohm, 1e-6);
  EXPECT_NEAR(fit.vx_V, m.vx_V, 1e-4);
  EXPECT_NEAR(fit.ld_H, m.ld_H - 5.0e-3, 1e-7);
}

// The jackknife standard error against the scatter of the estimate over many noise draws.
void check_jackknife(bool fit_vx) {
  PairSpec p;
  p.noise_V = 0.5;
  p.shape.g_ripple = 0.6;  // Vx identifiable enough that the joint fit is worth checking
  std::mt19937_64 rng(12345);
  const int runs = 150;
  std::vector<double> rs;
  double se_sum = 0.0;
  for (int n = 0; n < runs; ++n) {
    PairRun run;
    run_pair(p, run, &rng);
    const FitResult fit = solve_fit(run.recorder.sums(), options(fit_vx, true, p.truth.vx_V));
    ASSERT_TRUE(fit.valid);
    rs.push_back(fit.rs_ohm);
    se_sum += std::sqrt(fit.var_rs);
  }
  double mean = 0.0;
  for (double v : rs) mean += v;
  mean /= runs;
  double var = 0.0;
  for (double v : rs) var += (v - mean) * (v - mean);
  const double empirical = std::sqrt(var / (runs - 1));
  const double reported = se_sum / runs;
  EXPECT_GT(reported / empirical, 0.5) << "reported " << reported << " empirical " << empirical;
  EXPECT_LT(reported / empirical, 2.0) << "reported " << reported << " empirical " << empirical;
  // Unbiased: the mean is within a few standard errors of the mean of the truth.
  EXPECT_NEAR(mean, p.truth.rs_ohm, 4.0 * empirical / std::sqrt(runs) + 2e-4);
}

TEST(PairFit, JackknifeStandardErrorMatchesTheScatterWithVxHeld) { check_jackknife(false); }

TEST(PairFit, JackknifeStandardErrorMatchesTheScatterWithVxFitted) { check_jackknife(true); }

// ---- solve_means_fit: Rs and Vx across levels ----

BlockedSums pair_sums(double level, const Truth& truth, const Shape& shape) {
  PairSpec p;
  p.truth = truth;
  p.shape = shape;
  p.shape.f_A = 25.0 * level;
  PairRun run;
  run_pair(p, run);
  return run.recorder.sums();
}

TEST(MeansFit, RecoversRsAndVxFromTwoLevels) {
  Truth truth;
  Shape shape;
  shape.modulation = 0.0;  // flat injection: no inductive voltage in the means
  shape.g_ripple = 0.1;
  // The sign pattern saturates: dGd is the same at both levels while dId scales with F.
  const std::array<BlockedSums, 2> pairs{pair_sums(1.0, truth, shape), pair_sums(0.4, truth, shape)};
  const MeansFit fit = solve_means_fit(pairs.data(), 2, false);
  ASSERT_TRUE(fit.valid);
  EXPECT_NEAR(fit.rs_ohm, truth.rs_ohm, 2e-4);
  EXPECT_NEAR(fit.vx_V, truth.vx_V, 5e-3);
  EXPECT_GT(fit.identifiability, 0.05);
  // Within one pair the two regressors are nearly collinear: the sample fit on its own is
  // poorly identified compared with the means across levels.
  const FitResult single = solve_fit(pairs[0], options(true, false));
  EXPECT_LT(single.vx_identifiability, 0.01);
}

TEST(MeansFit, OneLevelOrProportionalLevelsCannotSeparateVx) {
  Truth truth;
  Shape shape;
  shape.modulation = 0.0;
  const BlockedSums one = pair_sums(1.0, truth, shape);
  EXPECT_FALSE(solve_means_fit(&one, 1, false).valid);
  // If the pattern scaled with F (it does not in a bridge), the levels would be proportional.
  Shape scaled = shape;
  std::array<BlockedSums, 2> pairs{};
  for (std::size_t j = 0; j < 2; ++j) {
    const double level = j == 0 ? 1.0 : 0.4;
    scaled.g_mean = 1.2 * level;
    scaled.g_ripple = 0.0;
    pairs[j] = pair_sums(level, truth, scaled);
  }
  const MeansFit fit = solve_means_fit(pairs.data(), 2, false);
  EXPECT_FALSE(fit.valid);
  EXPECT_LT(fit.identifiability, 1e-6);
}

// The design's identifiability is the levels' geometry: with two pairs the fit passes through
// both means whatever their weights (a model error in either moves Vx by what the geometry
// allows), so a noisier lower level changes the error bars and the weighted figure, not the
// geometry. The figures are a 24 V truck's standstill event (F = 62.5 A and 0.4 F, the sign
// pattern saturated at 8/3): the weighted 1 - rho^2 read 0.02-0.04 there, and the scheduler,
// which took it, never learned a Vx measured to 3 mV.
TEST(MeansFit, TheDesignsIdentifiabilityIsTheLevelsGeometryNotTheirWeights) {
  const double rs = 0.0096;
  const double vx = 0.665;
  auto means = [&](double x, double w) {
    const double g = 8.0 / 3.0;
    return std::optional<PairMeans>(PairMeans{.x_rs = x, .x_vx = g, .y = rs * x + vx * g, .w = w});
  };
  const double x_hi = 125.0;
  const double x_lo = 50.0;
  // 1 - (x_hi + x_lo)^2 g^2 / ((x_hi^2 + x_lo^2) 2 g^2)
  const double geometry = 1.0 - (x_hi + x_lo) * (x_hi + x_lo) / (2.0 * (x_hi * x_hi + x_lo * x_lo));
  const std::array<std::optional<PairMeans>, 2> even{means(x_hi, 5e5), means(x_lo, 5e5)};
  const std::array<std::optional<PairMeans>, 2> uneven{means(x_hi, 5e5), means(x_lo, 3e4)};
  const MeansFit a = solve_means_fit(even.data(), 2);
  const MeansFit b = solve_means_fit(uneven.data(), 2);
  ASSERT_TRUE(a.valid);
  ASSERT_TRUE(b.valid);
  EXPECT_NEAR(a.design_identifiability, geometry, 1e-12);
  EXPECT_NEAR(b.design_identifiability, geometry, 1e-12);
  EXPECT_NEAR(geometry, 0.155, 1e-3);
  // Even weights: the weighted figure is the geometry; uneven, it falls below the 0.05 the
  // scheduler asks by default.
  EXPECT_NEAR(a.identifiability, geometry, 1e-12);
  EXPECT_LT(b.identifiability, 0.05);
  // Both pass through the means exactly; the weights show in the error bars.
  EXPECT_NEAR(b.rs_ohm, rs, 1e-12);
  EXPECT_NEAR(b.vx_V, vx, 1e-9);
  EXPECT_GT(b.var_vx, 2.0 * a.var_vx);
}

// ---- closed-loop sensor noise: the sample fit against the means ----

// A d-axis current loop at standstill, simulated here period by period: a PI (Kp = wc L,
// Ki = wc Rs) acting on the *measured* current, its voltage applied one period later to the
// R-L winding, the sensor adding white noise. The recorder sees what a drive sees: the
// measured currents and the commanded voltages. One bipolar pair, time-matched.
BlockedSums closed_loop_pair(double f_A, double noise_A, std::mt19937_64& rng) {
  const double rs = 0.15;
  const double l = 5.5e-3;
  const double wc = 2000.0;
  const double kp = wc * l;
  const double ki = wc * rs;
  std::normal_distribution<double> noise(0.0, noise_A);
  PairRecorder rec(2048);
  PairFitConfig cfg;
  cfg.ld_H = l;
  cfg.lq_H = l;
  cfg.filter_length = 8;
  rec.start(cfg, MatchBy::kTime, 1.0);
  double i_true = 0.0;
  double integral = 0.0;
  double v_next = 0.0;
  double i_meas_prev = 0.0;
  double t = 0.0;
  // Each recording: 20 ms to settle at the level, then 50 ms recorded.
  for (int recording = 1; recording <= 2; ++recording) {
    const double ref = recording == 1 ? f_A : -f_A;
    const double origin = t + 0.02;
    if (recording == 2) {
      rec.begin_second(origin);
    }
    while (t < origin + 0.05) {
      // The period [t, t + T] under the voltage commanded one period earlier (exact R-L step).
      const double v = v_next;
      const double a = std::exp(-kPeriod * rs / l);
      const double i_end = v / rs + (i_true - v / rs) * a;
      const double i_meas = i_end + noise(rng);
      // The controller at the end of the period.
      const double e = ref - i_meas;
      integral += ki * kPeriod * e;
      v_next = kp * e + integral;
      PeriodSample s;
      s.time_s = t + 0.5 * kPeriod;
      s.theta_e_rad = 0.0;
      s.i_A = {0.5 * (i_meas_prev + i_meas), 0.0};
      s.di_dt_A_s = {(i_meas - i_meas_prev) / kPeriod, 0.0};
      s.v_V = {v, 0.0};
      if (s.time_s >= origin) {
        if (recording == 1) {
          rec.add_first(s);
        } else {
          rec.add_second(s);
        }
      }
      i_meas_prev = i_meas;
      i_true = i_end;
      t += kPeriod;
    }
  }
  return rec.sums();
}

TEST(MeansFit, SensorNoiseInTheCurrentLoopPullsTheSampleFitLowButNotTheMeans) {
  // Without noise both read Rs; with 1 A of sensor noise (exaggerated so that the effect
  // stands far above the scatter of 40 pairs) the sample-by-sample slope is pulled low,
  // because the loop answers each noise sample with -Kp times it in the very voltage the fit
  // regresses on the noisy current. The means over the recordings are not.
  std::mt19937_64 rng(7);
  const double rs = 0.15;
  double sample_sum = 0.0;
  double means_sum = 0.0;
  double means_sq = 0.0;
  const int n = 40;
  for (int k = 0; k < n; ++k) {
    const BlockedSums sums = closed_loop_pair(10.0, 1.0, rng);
    const FitResult sample = solve_fit(sums, options(false, true, 0.0));
    const MeansFit means = solve_means_fit_fixed_vx(&sums, 1, true, 0.0);
    ASSERT_TRUE(sample.valid);
    ASSERT_TRUE(means.valid);
    EXPECT_NEAR(means.drs_dvx, 0.0, 1e-12);  // no dead-time pattern in this loop
    sample_sum += sample.rs_ohm;
    means_sum += means.rs_ohm;
    means_sq += means.rs_ohm * means.rs_ohm;
  }
  const double sample_mean = sample_sum / n;
  const double means_mean = means_sum / n;
  const double means_sem = std::sqrt((means_sq / n - means_mean * means_mean) / (n - 1));
  EXPECT_LT(sample_mean, rs * 0.98) << "sample fit " << sample_mean;  // about -2.7 %
  EXPECT_NEAR(means_mean, rs, std::max(4.0 * means_sem, 1e-4)) << "means " << means_mean << " +- " << means_sem;

  std::mt19937_64 quiet(7);
  const BlockedSums clean = closed_loop_pair(10.0, 0.0, quiet);
  EXPECT_NEAR(solve_fit(clean, options(false, true, 0.0)).rs_ohm, rs, 1e-4);
  EXPECT_NEAR(solve_means_fit_fixed_vx(&clean, 1, true, 0.0).rs_ohm, rs, 1e-4);
}

TEST(MeansFit, FixedVxTakesTheGivenInverterVoltage) {
  Truth truth;
  Shape shape;
  shape.modulation = 0.0;
  const std::array<BlockedSums, 2> pairs{pair_sums(1.0, truth, shape), pair_sums(0.4, truth, shape)};
  const MeansFit right = solve_means_fit_fixed_vx(pairs.data(), 2, false, truth.vx_V);
  ASSERT_TRUE(right.valid);
  EXPECT_NEAR(right.rs_ohm, truth.rs_ohm, 2e-4);
  EXPECT_DOUBLE_EQ(right.vx_V, truth.vx_V);
  // A wrong Vx moves Rs by exactly drs_dvx per volt (the fit is linear in it).
  const MeansFit wrong = solve_means_fit_fixed_vx(pairs.data(), 2, false, truth.vx_V + 0.5);
  EXPECT_LT(right.drs_dvx, 0.0);
  EXPECT_NEAR(wrong.rs_ohm - right.rs_ohm, 0.5 * right.drs_dvx, 1e-9);
  EXPECT_FALSE(solve_means_fit_fixed_vx(pairs.data(), 0, false, truth.vx_V).valid);
}

// solve_fit's own small solver (a written-out Cholesky, the condition from the eigenvalues in
// closed form) against Eigen's general least squares on the same rows: the estimates, the
// residual, the reciprocal condition, and the jackknife's leave-one-block-out solves, on a
// well-conditioned design and on a nearly collinear one (rcond about 5e-5, below the
// min_condition guard).
TEST(PairFit, TheSmallSolverAgreesWithAGeneralLeastSquaresSolver) {
  for (const double collinear : {0.0, 0.9999}) {
    std::mt19937 rng(7);
    std::normal_distribution<double> n01(0.0, 1.0);
    const Eigen::Vector3d theta(0.15, 2.0, 6.0e-3);
    const int rows = 400;
    Eigen::MatrixXd x(rows, 3);
    Eigen::VectorXd y(rows);
    BlockedSums sums;
    for (int k = 0; k < rows; ++k) {
      const double a = n01(rng);
      const double b = collinear * a + std::sqrt(1.0 - collinear * collinear) * n01(rng);
      const std::array<double, kRegressors> row{5.0 * a, 0.3 * b, 40.0 * n01(rng)};
      x.row(k) << row[0], row[1], row[2];
      y(k) = x.row(k).dot(theta) + 0.01 * n01(rng);
      sums.blocks[static_cast<std::size_t>(k % kFitBlocks)].add(row, y(k));
    }
    FitOptions o;
    o.fit_vx = true;
    o.fit_ld = true;
    const FitResult fit = solve_fit(sums, o);
    ASSERT_TRUE(fit.valid) << "collinear " << collinear;
    const Eigen::Vector3d ls = x.colPivHouseholderQr().solve(y);
    EXPECT_NEAR(fit.rs_ohm, ls(0), 1e-9 * (1.0 + std::abs(ls(0))) / (1.0 - collinear));
    EXPECT_NEAR(fit.vx_V, ls(1), 1e-9 * (1.0 + std::abs(ls(1))) / (1.0 - collinear));
    EXPECT_NEAR(fit.ld_H, ls(2), 1e-11 / (1.0 - collinear));
    EXPECT_NEAR(fit.residual_rms_V, std::sqrt((x * ls - y).squaredNorm() / rows), 1e-6);
    // The condition of the column-scaled normal matrix, from an independent eigen-solver.
    Eigen::Matrix3d xtx = x.transpose() * x;
    const Eigen::Vector3d scale = xtx.diagonal().cwiseSqrt().cwiseInverse();
    xtx = scale.asDiagonal() * xtx * scale.asDiagonal();
    const Eigen::Vector3d ev = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(xtx).eigenvalues();
    EXPECT_NEAR(fit.condition, ev.minCoeff() / ev.maxCoeff(), 1e-9) << "collinear " << collinear;
    // The jackknife from eight general solves.
    Eigen::VectorXd rs(kFitBlocks);
    for (int b = 0; b < kFitBlocks; ++b) {
      std::vector<int> keep;
      for (int k = 0; k < rows; ++k) {
        if (k % kFitBlocks != b) keep.push_back(k);
      }
      Eigen::MatrixXd xb(static_cast<Eigen::Index>(keep.size()), 3);
      Eigen::VectorXd yb(static_cast<Eigen::Index>(keep.size()));
      for (std::size_t j = 0; j < keep.size(); ++j) {
        xb.row(static_cast<Eigen::Index>(j)) = x.row(keep[j]);
        yb(static_cast<Eigen::Index>(j)) = y(keep[j]);
      }
      rs(b) = xb.colPivHouseholderQr().solve(yb)(0);
    }
    const double var = (rs.array() - rs.mean()).square().sum() * (kFitBlocks - 1.0) / kFitBlocks;
    EXPECT_NEAR(fit.var_rs, var, 1e-6 * var) << "collinear " << collinear;
  }
}

TEST(BlockedSums, TotalIsTheSumOfTheBlocksAndAddIsBlockwise) {
  BlockedSums a;
  BlockedSums b;
  for (int k = 0; k < kFitBlocks; ++k) {
    a.blocks[static_cast<std::size_t>(k)].add(std::array<double, kRegressors>{1.0 * k, 2.0, 0.5}, 3.0 + k);
    b.blocks[static_cast<std::size_t>(k)].add(std::array<double, kRegressors>{-1.0, 1.0, 0.0}, 1.0);
  }
  a.add(b);
  const FitSums t = a.total();
  EXPECT_DOUBLE_EQ(t.n, 2.0 * kFitBlocks);
  // sum over k of (k^2 + 1)
  double xx = 0.0, xy = 0.0, y = 0.0;
  for (int k = 0; k < kFitBlocks; ++k) {
    xx += k * k + 1.0;
    xy += k * (3.0 + k) - 1.0;
    y += 3.0 + k + 1.0;
  }
  EXPECT_DOUBLE_EQ(t.xtx[kRegRs][kRegRs], xx);
  EXPECT_DOUBLE_EQ(t.xty[kRegRs], xy);
  EXPECT_DOUBLE_EQ(t.sum_y, y);
  FitSums back = t;
  back.add(t, -1.0);
  EXPECT_DOUBLE_EQ(back.n, 0.0);
  EXPECT_DOUBLE_EQ(back.yty, 0.0);
}

// A recording of kFitBlocks whole turns or more is cut into kFitBlocks blocks (each a turn or
// more), a shorter one into kFitBlocksShort. With white noise on vd, the jackknife's variance of
// Rs is itself a random number whose relative spread is about sqrt(2 / (B - 1)): 0.53 with 8
// blocks, 0.37 with 16. Events weighed by such variances lean on whichever pair drew a small
// one (docs/estimator.md section 3, "How many blocks"). Over 150 noisy pairs of 20 turns, the
// spread must be below 0.45; pairs of 2 turns, as many samples, keep 8 blocks and spread more.
TEST(PairFit, ARecordingOfManyTurnsEstimatesItsVarianceFromSixteenBlocks) {
  std::mt19937_64 rng(20261205);
  auto spread = [&](double arc_rad, double omega_rad_s, int& used) {
    std::vector<double> var;
    for (int k = 0; k < 150; ++k) {
      PairSpec p;
      p.truth.kd6 = 0.0;
      p.truth.kq6 = 0.0;
      p.ld_config_H = p.truth.ld_H;  // nothing but the noise in the residual
      p.omega1_rad_s = p.omega2_rad_s = omega_rad_s;
      p.arc_rad = arc_rad;
      p.dtheta_rad = std::ceil(arc_rad / (kTwoPi * 3.0) + 1.0) * kTwoPi * 3.0;
      p.noise_V = 2.0;
      PairRun run;
      run_pair(p, run, &rng);
      used = run.recorder.sums().used;
      const FitResult fit = solve_fit(run.recorder.sums(), options(false, false, p.truth.vx_V));
      EXPECT_TRUE(fit.valid);
      var.push_back(fit.var_rs);
    }
    double mean = 0.0;
    for (double v : var) mean += v;
    mean /= static_cast<double>(var.size());
    double sq = 0.0;
    for (double v : var) sq += (v - mean) * (v - mean);
    return std::sqrt(sq / static_cast<double>(var.size() - 1)) / mean;
  };
  int used_long = 0;
  int used_short = 0;
  // The same 420 samples a recording: 20 turns at 3000 rad/s, 2 turns at 300.
  const double long_spread = spread(20.0 * kTwoPi, 3000.0, used_long);
  const double short_spread = spread(2.0 * kTwoPi, 300.0, used_short);
  EXPECT_EQ(used_long, kFitBlocks);
  EXPECT_EQ(used_short, kFitBlocksShort);
  EXPECT_LT(long_spread, 0.45);
  EXPECT_GT(short_spread, 0.45);  // the same noise through 8 blocks: the figure the bound excludes
  std::printf("relative spread of the jackknife variance: %.3f (20 turns), %.3f (2 turns)\n", long_spread,
              short_spread);
}

}  // namespace
}  // namespace pmsm::core
