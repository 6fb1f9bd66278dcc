// InjectionScheduler driven by a small synthetic plant written here: the current follows the
// reference through a first-order lag, and every period's voltage is the model's
//
//   vd = Rs id - w Lq iq + Ld did/dt + Vx Gd + kd(theta) wm
//   vq = Rs iq + w Ld id + Ke wm + Vx Gq + kq(theta) wm
//
// with G the dq projection of the phase currents' soft-sign pattern (the bridge's dead-time
// error) and a 6th-harmonic EMF. The scheduler sees only SchedulerInput and PeriodSample.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "pmsm/core/injection.hpp"
#include "pmsm/core/injection_scheduler.hpp"

namespace pmsm::core {
namespace {

constexpr double kPeriod = 1e-4;

struct PlantModel {
  double rs_ohm = 0.16;             // at t = 0 ...
  double rs_rate_ohm_per_s = 0.0;  // ... and warming at this rate
  double vx_V = 1.5;
  double ld_H = 5.5e-3;
  double lq_H = 5.5e-3;
  // q-axis saturation: psi_q = (lq_H - lq_sat_H u^lq_sat_power) iq, u = (iq / lq_sat_current_A)^2.
  double lq_sat_H = 0.0;
  double lq_sat_current_A = 80.0;
  int lq_sat_power = 1;
  // The rotor angle's error (electrical): the measured frame lies this far from the rotor's,
  // and the d axis holds that share of the EMF (to first order).
  double angle_error_rad = 0.0;
  // A d-axis voltage the fit does not model while |id| lies below small_id_A (the bridge's
  // pattern, which the model of its zero crossings holds less well at a small level).
  double small_id_vd_V = 0.0;
  double small_id_A = 0.0;
  double ke_V_s_per_rad = 0.9716;  // phase peak per mechanical rad/s (Eq. 3)
  int pole_pairs = 3;
  double band_A = 1.0;             // soft-sign band of the bridge error
  double kd6 = 0.05;               // EMF harmonics, V s/rad
  double kq6 = 0.03;
  double current_tau_s = 0.3e-3;   // closed current loop
  double ripple_A = 0.005;
  double ripple_Hz = 1700.0;
};

// Eq. 24, written out here independently of core/window.
double modified_blackman(double tn, double tw) {
  if (std::abs(tn) > tw) return 0.0;
  return 0.625 + 0.5 * std::cos(kPi * tn / tw) - 0.125 * std::cos(2.0 * kPi * tn / tw);
}

double soft(double i, double band) { return std::clamp(i / band, -1.0, 1.0); }

Dq sign_pattern(const Dq& i, double theta, double band) {
  const AlphaBeta ab = inverse_park(i, theta);
  const Abc abc = inverse_clarke(ab);
  const Abc g{soft(abc.a, band), soft(abc.b, band), soft(abc.c, band)};
  return park(clarke(g), theta);
}

// Every setting the tests depend on, spelled out (the library's defaults may move).
InjectionConfig test_config() {
  InjectionConfig c;
  c.method = InjectionMethod::kFixedMagnitude;
  c.separation = Separation::kBipolar;
  c.f_A = 25.0;
  c.f_min_A = 5.0;
  c.levels = {1.0, 0.4, 0.0, 0.0};
  c.level_count = 2;
  c.first_event_s = 0.01;
  c.interval_s = 0.5;
  c.retry_s = 1.0;
  c.window = WindowKind::kModifiedBlackman;
  c.tw_s = 0.004;
  c.settle_s = 0.002;
  c.record_arc_rad = kTwoPi;
  c.record_time_s = 0.05;
  c.record_min_time_s = 0.01;  // one electrical turn at 300 rad/s
  c.mechanical_harmonics = true;
  c.pole_pairs = 3;
  c.min_speed_for_angle_rad_s = 30.0;
  c.unipolar_polarity = -1;
  c.current_limit_A = 80.0;
  c.headroom_margin_V = 15.0;
  c.max_torque_disturbance_Nm = 0.0;
  c.max_speed_change_fraction = 0.02;
  c.max_speed_change_rad_s = 3.0;
  c.max_load_change_A = 1.5;
  c.max_residual_V = 3.0;
  c.min_condition = 1e-4;
  c.rs_min_ohm = 0.09;
  c.rs_max_ohm = 0.27;
  c.fit_dead_time = true;
  c.fit_inductance = true;
  c.vx_initial_V = 0.0;
  c.vx_initial_std_V = 3.0;
  c.vx_drift_fraction = 0.0;
  c.vx_drift_std_V = 0.005;
  c.vx_learning_max_iq_fraction = 0.5;
  c.vx_min_identifiability = 0.05;
  c.vx_learning_max_speed_rad_s = 600.0;
  c.ld_H = 5.5e-3;
  c.lq_H = 5.5e-3;
  c.learn_lq = true;
  c.lq_initial_std_fraction = 0.1;
  c.lq_drift_fraction = 0.002;
  c.lq_learning_min_voltage_V = 2.0;
  c.rs_nominal_ohm = 0.133;
  c.flux_linkage_Wb = 0.3239;
  return c;
}

struct StepRecord {
  double time_s = 0.0;
  double theta_e_rad = 0.0;
  SchedulerOutput out;
};

class Harness {
 public:
  explicit Harness(const InjectionConfig& config, double omega_e = 300.0)
      : scheduler(config, kPeriod, 4096), omega_e_rad_s(omega_e) {}

  // Runs until time t_end; the hook may change the operating point before each step.
  void run_until(double t_end) {
    while (time_s < t_end) {
      step();
    }
  }

  void step() {
    if (hook) hook(*this);
    SchedulerInput in;
    in.time_s = time_s;
    in.theta_e_rad = theta_e_rad;
    in.omega_e_rad_s = omega_e_rad_s;
    in.motoring_ref_A = motoring_A;
    in.voltage_limit_V = voltage_limit_V;
    in.current_limit_A = current_limit_A;
    in.enabled = enabled;
    in.release_motoring = release_motoring;
    in.request_now = request_now;
    in.rs_rate_ohm_per_s = tell_rs_rate ? plant.rs_rate_ohm_per_s : 0.0;
    // The controller builds a period's sample only when the scheduler says it reads one.
    const bool give = previous && (!sample_only_when_recording || scheduler.records(previous->theta_e_rad));
    const SchedulerOutput out = scheduler.step(in, give ? &*previous : nullptr);
    records.push_back({time_s, theta_e_rad, out});
    if (out.completed) pairs.push_back(*out.completed);
    if (out.estimate) estimates.push_back(*out.estimate);

    // The period [t, t + T]: the current moves towards the reference (exact first-order step).
    const Dq ref{motoring_A.d + out.injection_A.d, motoring_A.q + out.injection_A.q};
    const double a = std::exp(-kPeriod / plant.current_tau_s);
    const Dq i_end{ref.d + (current_A.d - ref.d) * a, ref.q + (current_A.q - ref.q) * a};
    PeriodSample s;
    s.time_s = time_s + 0.5 * kPeriod;
    s.theta_e_rad = theta_e_rad + 0.5 * omega_e_rad_s * kPeriod;
    s.omega_e_rad_s = omega_e_rad_s;
    s.omega_m_rad_s = omega_e_rad_s / plant.pole_pairs;
    // A small ripple on top (as the PWM and the controller leave in a real drive), so that
    // no regressor is exactly zero; it enters the voltage like any other current.
    const double wr = kTwoPi * plant.ripple_Hz;
    const double ripple = plant.ripple_A * std::sin(wr * s.time_s);
    const double ripple_dt = plant.ripple_A * wr * std::cos(wr * s.time_s);
    s.i_A = {0.5 * (current_A.d + i_end.d) + ripple, 0.5 * (current_A.q + i_end.q)};
    s.di_dt_A_s = {(i_end.d - current_A.d) / kPeriod + ripple_dt, (i_end.q - current_A.q) / kPeriod};
    s.dead_time_pattern = sign_pattern(s.i_A, s.theta_e_rad, plant.band_A);
    const double w = s.omega_e_rad_s;
    const double wm = s.omega_m_rad_s;
    const double th = s.theta_e_rad;
    const double uq = s.i_A.q / plant.lq_sat_current_A;
    const double psi_q =
        (plant.lq_H - plant.lq_sat_H * (plant.lq_sat_power == 2 ? uq * uq * uq * uq : uq * uq)) * s.i_A.q;
    const double rs = plant.rs_ohm + plant.rs_rate_ohm_per_s * s.time_s;
    s.v_V.d = rs * s.i_A.d - w * psi_q + plant.ld_H * s.di_dt_A_s.d +
              plant.vx_V * s.dead_time_pattern.d + plant.kd6 * std::sin(6.0 * th + 0.3) * wm +
              plant.angle_error_rad * plant.ke_V_s_per_rad * wm +
              (std::abs(s.i_A.d) < plant.small_id_A ? plant.small_id_vd_V : 0.0);
    s.v_V.q = rs * s.i_A.q + w * plant.ld_H * s.i_A.d + plant.lq_H * s.di_dt_A_s.q +
              plant.ke_V_s_per_rad * wm + plant.vx_V * s.dead_time_pattern.q +
              plant.kq6 * std::cos(6.0 * th + 1.1) * wm;
    s.voltage_limited = flag_voltage_limited;
    s.modulation_clipped = flag_modulation_clipped;
    previous = s;
    current_A = i_end;
    theta_e_rad += omega_e_rad_s * kPeriod;
    time_s += kPeriod;
  }

  // Collapsed sequence of phases (consecutive duplicates removed).
  [[nodiscard]] std::vector<SchedulerPhase> phase_runs(double from_s = 0.0) const {
    std::vector<SchedulerPhase> out;
    for (const StepRecord& r : records) {
      if (r.time_s < from_s) continue;
      if (out.empty() || out.back() != r.out.phase) out.push_back(r.out.phase);
    }
    return out;
  }

  InjectionScheduler scheduler;
  PlantModel plant{};
  double time_s = 0.0;
  double theta_e_rad = 0.2;
  double omega_e_rad_s;
  Dq motoring_A{};
  Dq current_A{};
  double voltage_limit_V = 356.0;
  double current_limit_A = 80.0;
  bool enabled = true;
  bool release_motoring = false;
  bool request_now = false;
  bool flag_voltage_limited = false;
  bool flag_modulation_clipped = false;
  bool tell_rs_rate = true;  // pass the plant's dRs/dt as the thermal model's prediction
  bool sample_only_when_recording = false;  // as DriveController::step: InjectionScheduler::records
  std::function<void(Harness&)> hook;
  std::optional<PeriodSample> previous;
  std::vector<StepRecord> records;
  std::vector<PairResult> pairs;
  std::vector<EventEstimate> estimates;
};

using P = SchedulerPhase;

TEST(InjectionScheduler, BipolarPhaseSequence) {
  Harness h(test_config());
  h.run_until(0.4);
  const std::vector<P> pair = {P::kRampUp, P::kSettle, P::kRecord1, P::kRampDown, P::kRampUp,
                               P::kSettle, P::kWaitArc, P::kRecord2, P::kRampDown, P::kIdle};
  std::vector<P> expected = {P::kIdle};
  expected.insert(expected.end(), pair.begin(), pair.end());
  expected.insert(expected.end(), pair.begin(), pair.end());
  EXPECT_EQ(h.phase_runs(), expected);
  ASSERT_EQ(h.pairs.size(), 2U);
  ASSERT_EQ(h.estimates.size(), 1U);
  EXPECT_EQ(h.pairs[0].level_index, 0);
  EXPECT_EQ(h.pairs[1].level_index, 1);
  EXPECT_DOUBLE_EQ(h.pairs[0].f_A, 25.0);
  EXPECT_DOUBLE_EQ(h.pairs[1].f_A, 10.0);
}

TEST(InjectionScheduler, UnipolarPhaseSequence) {
  InjectionConfig c = test_config();
  c.separation = Separation::kUnipolar;
  Harness h(c);
  h.motoring_A = {0.0, 5.0};
  h.run_until(0.4);
  const std::vector<P> pair = {P::kSettle, P::kRecord1, P::kRampUp, P::kSettle, P::kWaitArc,
                               P::kRecord2, P::kRampDown, P::kIdle};
  std::vector<P> expected = {P::kIdle};
  expected.insert(expected.end(), pair.begin(), pair.end());
  expected.insert(expected.end(), pair.begin(), pair.end());
  EXPECT_EQ(h.phase_runs(), expected);
  // Recording 1 carries no injection, recording 2 carries -F (unipolar_polarity = -1).
  for (const StepRecord& r : h.records) {
    if (r.out.phase == P::kRecord1) {
      EXPECT_EQ(r.out.injection_A.d, 0.0);
    }
    if (r.out.phase == P::kRecord2) {
      EXPECT_TRUE(r.out.injection_A.d == -25.0 || r.out.injection_A.d == -10.0);
    }
  }
}

// Runs of one phase: index of the first step and the number of steps.
struct PhaseRun {
  P phase;
  std::size_t first;
  std::size_t length;
};

std::vector<PhaseRun> runs_of(const Harness& h) {
  std::vector<PhaseRun> out;
  for (std::size_t k = 0; k < h.records.size(); ++k) {
    const P p = h.records[k].out.phase;
    if (out.empty() || out.back().phase != p) {
      out.push_back({p, k, 1});
    } else {
      ++out.back().length;
    }
  }
  return out;
}

TEST(InjectionScheduler, InjectionCurrentFollowsTheWindowAndTheLevels) {
  InjectionConfig c = test_config();
  Harness h(c);
  h.run_until(0.4);
  const std::vector<PhaseRun> runs = runs_of(h);
  int ramps_checked = 0;
  int pair = 0;
  int ramp_in_pair = 0;
  double level_before = 0.0;  // level (units of F) at the end of the previous run
  // Bipolar: up to +F, down to 0, up to -F, down to 0.
  const std::array<double, 4> targets{1.0, 0.0, -1.0, 0.0};
  for (const PhaseRun& run : runs) {
    if (run.phase == P::kIdle) {
      if (run.first > 0) ++pair;
      level_before = 0.0;
      ramp_in_pair = 0;
      continue;
    }
    const double f = pair == 0 ? 25.0 : 10.0;
    const double t_start = h.records[run.first].time_s;
    if (run.phase == P::kRampUp || run.phase == P::kRampDown) {
      ASSERT_LT(ramp_in_pair, 4);
      const double to = targets[static_cast<std::size_t>(ramp_in_pair)];
      EXPECT_EQ(run.phase == P::kRampDown, to == 0.0);
      for (std::size_t k = run.first; k < run.first + run.length; ++k) {
        const double elapsed = h.records[k].time_s - t_start;
        const double e = modified_blackman(std::min(elapsed, c.tw_s) - c.tw_s, c.tw_s);
        const double expected = f * (level_before + (to - level_before) * e);
        EXPECT_NEAR(h.records[k].out.injection_A.d, expected, 1e-9) << "step " << k;
        EXPECT_EQ(h.records[k].out.injection_A.q, 0.0);
      }
      // A ramp lasts Tw (one step of rounding either way).
      EXPECT_NEAR(static_cast<double>(run.length) * kPeriod, c.tw_s, 1.5 * kPeriod);
      level_before = to;
      ++ramp_in_pair;
      ++ramps_checked;
    } else {
      for (std::size_t k = run.first; k < run.first + run.length; ++k) {
        EXPECT_NEAR(h.records[k].out.injection_A.d, f * level_before, 1e-12) << "step " << k;
      }
      if (run.phase == P::kSettle) {
        EXPECT_NEAR(static_cast<double>(run.length) * kPeriod, c.settle_s, 1.5 * kPeriod);
      }
    }
  }
  EXPECT_EQ(ramps_checked, 8);
}

TEST(InjectionScheduler, BlackmanWindowEdge) {
  InjectionConfig c = test_config();
  c.window = WindowKind::kBlackman;
  Harness h(c);
  h.run_until(0.06);
  const std::vector<PhaseRun> runs = runs_of(h);
  ASSERT_GE(runs.size(), 2U);
  ASSERT_EQ(runs[1].phase, P::kRampUp);
  for (std::size_t k = runs[1].first; k < runs[1].first + runs[1].length; ++k) {
    const double tn = h.records[k].time_s - h.records[runs[1].first].time_s - c.tw_s;
    const double b = 0.42 + 0.5 * std::cos(kPi * tn / c.tw_s) + 0.08 * std::cos(2.0 * kPi * tn / c.tw_s);  // Eq. 23
    EXPECT_NEAR(h.records[k].out.injection_A.d, 25.0 * b, 1e-9);
  }
}

// Angles of the first sample of recording 1 and of recording 2 of every pair, from the phases:
// recording 1 takes the sample handed over in the step after it was entered; recording 2 the
// one handed over in the step that entered it.
struct PairAngles {
  double first1;
  double first2;
  double extent_end1;  // angle of the last sample of recording 1
};

std::vector<PairAngles> pair_angles(const Harness& h) {
  std::vector<PairAngles> out;
  const std::vector<PhaseRun> runs = runs_of(h);
  const double half = 0.5 * h.omega_e_rad_s * kPeriod;
  PairAngles current{};
  for (const PhaseRun& run : runs) {
    if (run.phase == P::kRecord1) {
      current.first1 = h.records[run.first].theta_e_rad + half;  // sample of the period after step `first`
      // The step that leaves Record1 has recorded the sample of the period before it.
      current.extent_end1 = h.records[run.first + run.length].theta_e_rad - half;
    }
    if (run.phase == P::kRecord2) {
      current.first2 = h.records[run.first].theta_e_rad - half;
      out.push_back(current);
    }
  }
  return out;
}

// mechanical_min_speed: InjectionConfig::mechanical_harmonics_min_speed_rad_s (mechanical).
// omega_e may be negative: the angles then fall, and every span is taken by its size.
void check_dtheta(bool mechanical, double omega_e, double mechanical_min_speed = 10.0) {
  InjectionConfig c = test_config();
  c.mechanical_harmonics = mechanical;
  c.mechanical_harmonics_min_speed_rad_s = mechanical_min_speed;
  Harness h(c, omega_e);
  h.run_until(0.4);
  const std::vector<PairAngles> angles = pair_angles(h);
  ASSERT_EQ(angles.size(), 2U) << "omega_e " << omega_e;
  const double speed = std::abs(omega_e);
  const double step = std::abs(h.omega_e_rad_s) * kPeriod;
  const bool whole_mechanical_turns = mechanical && speed >= mechanical_min_speed * c.pole_pairs;
  const double unit = whole_mechanical_turns ? kTwoPi * c.pole_pairs : kTwoPi;
  for (const PairAngles& a : angles) {
    const double extent = std::abs(a.extent_end1 - a.first1);
    // Recording 1 spans whole turns, at least one and at least record_min_time_s: at least
    // that, less than a period more.
    const double turns = std::ceil(std::max(kTwoPi, speed * c.record_min_time_s) / kTwoPi - 1e-9);
    EXPECT_GE(extent, turns * kTwoPi - 1e-9) << "omega_e " << omega_e;
    EXPECT_LT(extent, turns * kTwoPi + step + 1e-9) << "omega_e " << omega_e;
    const double dtheta = std::abs(a.first2 - a.first1);
    // Recording 2 starts at the first sample at or past origin + dTheta.
    const double multiple = std::floor(dtheta / unit + 1e-9);
    EXPECT_GE(multiple, 1.0);
    EXPECT_LT(dtheta - multiple * unit, step + 1e-9) << "omega_e " << omega_e;
    // The smallest multiple that leaves room for recording 1 and the transition (two ramps,
    // settling and 4 periods at the present speed).
    const double needed = extent + std::abs(h.omega_e_rad_s) * (2.0 * c.tw_s + c.settle_s + 4.0 * kPeriod);
    EXPECT_EQ(multiple, std::max(1.0, std::ceil(needed / unit))) << "omega_e " << omega_e;
  }
}

TEST(InjectionScheduler, DThetaIsAMultipleOfTwoPiPForMechanicalHarmonics) {
  check_dtheta(true, 300.0);
  check_dtheta(true, 900.0);
}
// Slower than a mechanical turn in 1 / mechanical_harmonics_min_speed_rad_s: a pair spans an
// electrical turn, not a slow mechanical one (300 electrical rad/s at p = 3 is 100 rad/s).
TEST(InjectionScheduler, DThetaIsAMultipleOfTwoPiBelowTheMechanicalHarmonicsSpeed) {
  check_dtheta(true, 300.0, 101.0);
  check_dtheta(true, 300.0, 99.0);  // just above it: whole mechanical turns again
}
TEST(InjectionScheduler, DThetaIsAMultipleOfTwoPiForElectricalHarmonics) {
  check_dtheta(false, 300.0);
  check_dtheta(false, 900.0);  // here the transition (ramps, settling) needs a turn of its own
}
// Turning backwards, the same spans: whole mechanical turns above the speed, electrical ones
// below it and without the mechanical harmonics (InjectionScheduler::delta_theta takes |w|).
TEST(InjectionScheduler, DThetaIsTheSameTurningBackwards) {
  check_dtheta(true, -300.0);
  check_dtheta(true, -900.0);
  check_dtheta(true, -300.0, 101.0);
  check_dtheta(true, -300.0, 99.0);
  check_dtheta(false, -900.0);
}

TEST(InjectionScheduler, PublishesOneEstimatePerEventNearTheTruth) {
  Harness h(test_config());
  h.run_until(0.9);  // two events, 0.5 s apart
  ASSERT_EQ(h.estimates.size(), 2U);
  ASSERT_EQ(h.pairs.size(), 4U);
  for (const PairResult& p : h.pairs) {
    EXPECT_EQ(p.outcome, PairOutcome::kAccepted) << to_string(p.outcome);
    EXPECT_FALSE(p.time_based);
  }
  for (const EventEstimate& e : h.estimates) {
    EXPECT_EQ(e.outcome, EventOutcome::kPublished);
    EXPECT_EQ(e.pairs, 2);
    // Light load, bipolar, below the learning speed: the levels determine Vx.
    EXPECT_TRUE(e.vx_learning);
    EXPECT_TRUE(e.vx_from_event);
    EXPECT_NEAR(e.rs_ohm, h.plant.rs_ohm, 2e-4);
    EXPECT_NEAR(e.vx_V, h.plant.vx_V, 0.01);
    EXPECT_GT(e.rs_std_ohm, 0.0);
    EXPECT_TRUE(e.has_emf);
    EXPECT_NEAR(e.ke_V_s_per_rad, h.plant.ke_V_s_per_rad, 5e-4);
  }
  // Events start interval_s apart.
  std::vector<double> starts;
  bool expecting_start = true;
  for (const StepRecord& r : h.records) {
    if (expecting_start && r.out.active) {
      starts.push_back(r.time_s);
      expecting_start = false;
    }
    if (r.out.estimate) expecting_start = true;
  }
  ASSERT_EQ(starts.size(), 2U);
  EXPECT_NEAR(starts[1] - starts[0], 0.5, 1.5 * kPeriod);
  // The prior carried to the next event is the fused value.
  EXPECT_NEAR(h.scheduler.vx_V(), h.plant.vx_V, 0.01);
}

// A winding warming during an event: its pairs saw different resistances. Referred to the
// event's time by the predicted rate, the joint fit keeps Vx and gives Rs at that time;
// without the rate the warming between the levels reads as inverter voltage.
TEST(InjectionScheduler, AWarmingWindingIsReferredToTheEventsTime) {
  PlantModel warming;
  warming.rs_rate_ohm_per_s = 0.02;  // 12.5 % of Rs a second, a fast heat-up
  auto run = [&](bool tell) {
    Harness h(test_config());
    h.plant = warming;
    h.tell_rs_rate = tell;
    h.run_until(0.3);
    return h.estimates;
  };
  const std::vector<EventEstimate> told = run(true);
  const std::vector<EventEstimate> blind = run(false);
  ASSERT_EQ(told.size(), 1U);
  ASSERT_EQ(blind.size(), 1U);
  ASSERT_EQ(told[0].outcome, EventOutcome::kPublished);
  const EventEstimate& e = told[0];
  // The time it belongs to lies inside the event, before its end.
  EXPECT_GT(e.measured_at_s, 0.01);
  EXPECT_LT(e.measured_at_s, e.time_s);
  const double rs_then = warming.rs_ohm + warming.rs_rate_ohm_per_s * e.measured_at_s;
  EXPECT_NEAR(e.joint_vx_V, warming.vx_V, 0.01);
  EXPECT_NEAR(e.joint_rs_ohm, rs_then, 2e-4);
  // Blind to the warming, the event's own fit moves Vx by twice that and more.
  EXPECT_GT(std::abs(blind[0].joint_vx_V - warming.vx_V), 0.02);
  EXPECT_LT(std::abs(e.joint_vx_V - warming.vx_V), 0.5 * std::abs(blind[0].joint_vx_V - warming.vx_V));
}

// A unipolar pair (0, then -F) measures Rs(t1) 0 - Rs(t2) (-F): the resistance of recording
// 2's time, not of the pair's middle. On a warming winding the event's estimate must say so.
TEST(InjectionScheduler, AUnipolarPairsRsBelongsToItsSecondRecording) {
  InjectionConfig c = test_config();
  c.separation = Separation::kUnipolar;
  c.vx_initial_V = 1.5;  // the plant's true value, held (unipolar pairs do not learn it)
  c.vx_initial_std_V = 0.001;
  PlantModel warming;
  warming.rs_rate_ohm_per_s = 0.02;
  Harness h(c);
  h.plant = warming;
  h.tell_rs_rate = true;
  h.motoring_A = {0.0, 5.0};
  h.run_until(0.45);
  ASSERT_EQ(h.estimates.size(), 1U);
  const EventEstimate& e = h.estimates[0];
  ASSERT_EQ(e.outcome, EventOutcome::kPublished);
  // The pair's middle lies 31 ms before recording 2's mean time here: placed there, the
  // estimate would be 6.3e-4 ohm off its time's resistance (measured with the middle).
  const double rs_then = warming.rs_ohm + warming.rs_rate_ohm_per_s * e.measured_at_s;
  EXPECT_NEAR(e.rs_ohm, rs_then, 1e-4);
  EXPECT_LT(e.measured_at_s, e.time_s);
}

// On a motoring point with a d current of its own (field weakening), a unipolar pair (0, then
// -F on top of -30 A) weighs its recordings' times by their whole d currents and dates its Rs
// beyond its second recording, here after the event's end. The event keeps that date (the drive
// holds the estimate until its time: DriveController::hold_estimate), and its Rs is that time's
// resistance, which a fit blind to the warming reads all the same: the date is the pair's.
TEST(InjectionScheduler, AnRsDatedAfterTheEventKeepsItsDate) {
  InjectionConfig c = test_config();
  c.separation = Separation::kUnipolar;
  c.level_count = 1;
  c.vx_initial_V = 1.5;  // the plant's true value, held (unipolar pairs do not learn it)
  c.vx_initial_std_V = 0.001;
  PlantModel warming;
  warming.rs_rate_ohm_per_s = 0.02;
  Harness h(c);
  h.plant = warming;
  h.motoring_A = {-30.0, 5.0};
  h.run_until(0.45);
  ASSERT_EQ(h.estimates.size(), 1U);
  const EventEstimate& e = h.estimates[0];
  ASSERT_EQ(e.outcome, EventOutcome::kPublished);
  EXPECT_GT(e.measured_at_s, e.time_s + 0.02);
  EXPECT_NEAR(e.rs_ohm, warming.rs_ohm + warming.rs_rate_ohm_per_s * e.measured_at_s, 1e-4);
  // The resistance of its publication lies further off than the tolerance above.
  EXPECT_GT(e.rs_ohm - (warming.rs_ohm + warming.rs_rate_ohm_per_s * e.time_s), 3e-4);
}

TEST(InjectionScheduler, EventRsIsConditionedOnTheFusedVx) {
  // A confident but wrong prior (1.0 V +- 1 mV; the plant has 1.5 V): the fused Vx stays at
  // the prior and Rs is the one that fits with Vx = 1.0 V. Each pair's mean satisfies
  // mean(y) = Rs mean(dId) + Vx mean(dGd); with Vx off by -0.5 V a pair alone gives
  // Rs + 0.5 mean(dGd) / mean(dId), about 0.16 + 0.5 * 2.54 / 50 = 0.185 ohm at F = 25 A and
  // 0.16 + 0.5 * 2.54 / 20 = 0.224 ohm at 10 A; the weighted fit lies between them.
  InjectionConfig c = test_config();
  c.vx_initial_V = 1.0;
  c.vx_initial_std_V = 0.001;
  Harness h(c);
  h.run_until(0.3);
  ASSERT_EQ(h.estimates.size(), 1U);
  const EventEstimate& e = h.estimates[0];
  ASSERT_EQ(e.outcome, EventOutcome::kPublished);
  EXPECT_TRUE(e.vx_from_event);
  EXPECT_NEAR(e.joint_vx_V, 1.5, 0.01);  // the event alone sees the truth
  EXPECT_NEAR(e.vx_V, 1.0, 0.01);        // fused: the prior dominates
  EXPECT_LT(e.vx_std_V, 0.0011);
  EXPECT_GT(e.rs_ohm, 0.180);
  EXPECT_LT(e.rs_ohm, 0.230);
}

// InjectionConfig::can_learn_vx (which the daemon's start-up check asks) says what the events
// do: at light load and low speed, an event learns Vx exactly when its configuration can.
TEST(InjectionScheduler, TheConfigurationsThatCanLearnVxAreThoseWhoseEventsDo) {
  struct Case {
    const char* name;
    std::function<void(InjectionConfig&)> set;
    bool learns;
  };
  const std::vector<Case> cases{
      {"bipolar, two levels", [](InjectionConfig&) {}, true},
      {"unipolar", [](InjectionConfig& c) { c.separation = Separation::kUnipolar; }, false},
      {"bipolar, one level", [](InjectionConfig& c) { c.level_count = 1; }, false},
      {"bipolar, two equal levels", [](InjectionConfig& c) { c.levels = {0.7, 0.7, 0.0, 0.0}; }, false},
      {"bridge term not fitted", [](InjectionConfig& c) { c.fit_dead_time = false; }, false},
  };
  for (const Case& k : cases) {
    InjectionConfig c = test_config();
    k.set(c);
    EXPECT_EQ(c.can_learn_vx(), k.learns) << k.name;
    Harness h(c);
    h.run_until(0.45);
    ASSERT_FALSE(h.estimates.empty()) << k.name;
    const EventEstimate& e = h.estimates[0];
    EXPECT_EQ(e.outcome, EventOutcome::kPublished) << k.name;
    EXPECT_EQ(e.vx_from_event, c.can_learn_vx()) << k.name;
  }
}

TEST(InjectionScheduler, UnipolarEventUsesTheVxPrior) {
  InjectionConfig c = test_config();
  c.separation = Separation::kUnipolar;
  c.vx_initial_V = 1.5;     // the plant's true value
  c.vx_initial_std_V = 0.01;
  Harness h(c);
  h.motoring_A = {0.0, 5.0};
  h.run_until(0.45);
  ASSERT_EQ(h.estimates.size(), 1U);
  const EventEstimate& e = h.estimates[0];
  EXPECT_EQ(e.outcome, EventOutcome::kPublished);
  EXPECT_FALSE(e.vx_learning);  // unipolar pairs do not reverse the current vector
  EXPECT_FALSE(e.vx_from_event);
  EXPECT_NEAR(e.rs_ohm, h.plant.rs_ohm, 2e-4);
  EXPECT_NEAR(e.vx_V, 1.5, 1e-12);
  // The mean d current is -F/2 here, so Eq. 34's w Ld id term matters for Ke.
  EXPECT_TRUE(e.has_emf);
  EXPECT_NEAR(e.ke_V_s_per_rad, h.plant.ke_V_s_per_rad, 5e-4);
}

// A unipolar pair is one-sided (0, then -F), as a field-weakening pair is: the sign pattern's
// error even in the pulse does not cancel, so its share of the bridge's term
// (field_weakening_pattern_error) widens the estimate's error bar as a shared error. A bipolar
// pair's estimate does not carry it.
TEST(InjectionScheduler, AUnipolarEstimateCarriesTheSignPatternsError) {
  const auto estimate = [](Separation separation, double pattern_error) {
    InjectionConfig c = test_config();
    c.separation = separation;
    c.vx_initial_V = 1.5;
    c.vx_initial_std_V = 0.01;
    c.field_weakening_pattern_error = pattern_error;
    Harness h(c);
    h.motoring_A = {0.0, 5.0};
    h.run_until(0.45);
    EXPECT_EQ(h.estimates.size(), 1U);
    return h.estimates.empty() ? EventEstimate{} : h.estimates[0];
  };
  const EventEstimate without = estimate(Separation::kUnipolar, 0.0);
  const EventEstimate with = estimate(Separation::kUnipolar, 0.05);
  ASSERT_EQ(with.outcome, EventOutcome::kPublished);
  EXPECT_EQ(with.rs_ohm, without.rs_ohm) << "the error bar, not the estimate";
  EXPECT_GT(with.rs_systematic_std_ohm, without.rs_systematic_std_ohm + 1e-5);
  EXPECT_GT(with.rs_std_ohm, without.rs_std_ohm);
  // The shared part grows by what the error bar grows by (both in quadrature).
  EXPECT_NEAR(with.rs_std_ohm * with.rs_std_ohm - without.rs_std_ohm * without.rs_std_ohm,
              with.rs_systematic_std_ohm * with.rs_systematic_std_ohm -
                  without.rs_systematic_std_ohm * without.rs_systematic_std_ohm,
              1e-12);
  const EventEstimate bipolar = estimate(Separation::kBipolar, 0.0);
  const EventEstimate bipolar_with = estimate(Separation::kBipolar, 0.05);
  EXPECT_EQ(bipolar_with.rs_std_ohm, bipolar.rs_std_ohm);
  EXPECT_EQ(bipolar_with.rs_systematic_std_ohm, bipolar.rs_systematic_std_ohm);
}

// Vx's drift between events goes with the bridge's error (InjectionConfig::vx_drift_fraction):
// the held Vx widens per event by the share of sqrt(Vx^2 + var(Vx)), the Vx held now (not the
// configured prior's), and an absolute part adds in quadrature: a 0.2 V bridge by 0.13 mV, the
// reference's 7.5 V one by 5 mV, a guess of 0 +- 3 V by the share of its 3 V. Unipolar events
// hold Vx, so each event's widening is the drift alone.
TEST(InjectionScheduler, VxDriftsByAShareOfTheBridgesError) {
  EXPECT_NEAR(kReferenceVxDriftFraction * kReferenceBridgeVx_V, 0.005, 1e-12);
  struct Held {
    double vx_V;
    double std_V;
  };
  for (const double absolute_V : {0.0, 0.003}) {
    for (const Held held : {Held{0.2, 0.01}, Held{7.5, 0.01}, Held{-0.2, 0.01}, Held{0.0, 3.0}}) {
      InjectionConfig c = test_config();
      c.separation = Separation::kUnipolar;
      c.vx_initial_V = 1.0;  // the configured prior, replaced below by what the drive holds
      c.vx_initial_std_V = 0.5;
      c.vx_drift_fraction = kReferenceVxDriftFraction;
      c.vx_drift_std_V = absolute_V;
      Harness h(c);
      InjectionScheduler::VxState state = h.scheduler.vx_state();
      state.vx_V = held.vx_V;
      state.vx_var = held.std_V * held.std_V;
      h.scheduler.set_vx_state(state);
      h.plant.vx_V = held.vx_V;
      h.motoring_A = {0.0, 5.0};
      h.run_until(0.45);
      const std::string what = "held " + std::to_string(held.vx_V) + " +- " + std::to_string(held.std_V) +
                               " V, absolute part " + std::to_string(absolute_V) + " V";
      ASSERT_EQ(h.estimates.size(), 1U) << what;
      ASSERT_EQ(h.estimates[0].outcome, EventOutcome::kPublished) << what;
      ASSERT_FALSE(h.estimates[0].vx_from_event) << what;
      const double var_before = held.std_V * held.std_V;
      const double grown_sq = h.scheduler.vx_std_V() * h.scheduler.vx_std_V() - var_before;
      const double share_sq = kReferenceVxDriftFraction * kReferenceVxDriftFraction * (held.vx_V * held.vx_V + var_before);
      EXPECT_NEAR(std::sqrt(std::max(grown_sq, 0.0)), std::sqrt(absolute_V * absolute_V + share_sq), 1e-8) << what;
      EXPECT_EQ(h.scheduler.vx_V(), held.vx_V) << what;
    }
  }
}

// The same with the machine's Ld 10 % above the commissioned one: the pair measures Ld from
// its recordings' q-axis difference (d(w id) = w F), so Ke does not take the commissioned
// Ld's error. With the commissioned Ld it would read Ke 2 % low (0.1 Ld w <id> / wm: 0.55 mH x
// 300 rad/s x 12.5 A / 100 rad/s), 17 C of magnet.
TEST(InjectionScheduler, UnipolarKeDoesNotTakeTheCommissionedLdError) {
  InjectionConfig c = test_config();
  c.separation = Separation::kUnipolar;
  c.vx_initial_V = 1.5;
  c.vx_initial_std_V = 0.01;
  Harness h(c);
  h.plant.ld_H = 1.1 * c.ld_H;
  h.motoring_A = {0.0, 5.0};
  h.run_until(0.45);
  ASSERT_EQ(h.estimates.size(), 1U);
  const EventEstimate& e = h.estimates[0];
  ASSERT_EQ(e.outcome, EventOutcome::kPublished);
  ASSERT_TRUE(e.has_emf);
  EXPECT_NEAR(e.ke_V_s_per_rad, h.plant.ke_V_s_per_rad, 5e-4);
}

// A salient machine under load, the speed loop holding the torque: it answers the
// injection's reluctance torque with iq = iq0 psi / (psi + (Ld - Lq) id), so iq moves with
// the injection and the Lq d(w iq) term of Eq. 37 carries the commissioning error of Lq into
// Rs. The pairs' d-axis means reveal the true Lq.
struct SalientRun {
  std::vector<EventEstimate> estimates;
  double lq_H = 0.0;
};

SalientRun run_salient(bool learn, InjectionMethod method = InjectionMethod::kFixedMagnitude, double iq0 = 4.0,
                       Separation separation = Separation::kBipolar,
                       double min_voltage_V = test_config().lq_learning_min_voltage_V) {
  InjectionConfig c = test_config();
  c.method = method;
  c.separation = separation;
  c.lq_learning_min_voltage_V = min_voltage_V;
  c.f_A = 10.0;
  c.f_min_A = 2.0;
  c.lq_H = 7.425e-3;          // commissioned 10 % low
  c.learn_lq = learn;
  c.vx_initial_V = 1.5;       // known inverter voltage: this test is about Lq alone
  c.vx_initial_std_V = 0.01;
  Harness h(c);
  h.plant.lq_H = 8.25e-3;
  const double psi = c.flux_linkage_Wb;
  h.motoring_A = {0.0, iq0};
  h.hook = [&](Harness& x) {
    const double id = x.records.empty() ? 0.0 : x.records.back().out.injection_A.d;
    x.motoring_A.q = iq0 * psi / (psi + (x.plant.ld_H - x.plant.lq_H) * id);
  };
  h.run_until(3.0);
  return {h.estimates, h.scheduler.lq_H()};
}

TEST(InjectionScheduler, LearnsLqOnASalientMachineAndRemovesItsBias) {
  const double rs = PlantModel{}.rs_ohm;
  const SalientRun fixed = run_salient(false);
  const SalientRun learned = run_salient(true);
  ASSERT_GE(fixed.estimates.size(), 5U);
  ASSERT_EQ(learned.estimates.size(), fixed.estimates.size());
  // Without learning every event is off by the same few per cent, and says so: its standard
  // deviation carries the commissioned Lq's prior (10 %) through the pairs' Lq term, as a
  // part shared by the estimates that follow.
  for (const EventEstimate& e : fixed.estimates) {
    ASSERT_EQ(e.outcome, EventOutcome::kPublished);
    EXPECT_GT(std::abs(e.rs_ohm - rs), 0.02 * rs) << e.rs_ohm;
    EXPECT_DOUBLE_EQ(e.lq_H, 7.425e-3);
    EXPECT_LT(std::abs(e.rs_ohm - rs), 2.0 * e.rs_std_ohm) << "the band holds the Lq error";
    EXPECT_GT(e.rs_systematic_std_ohm, 0.5 * std::abs(e.rs_ohm - rs));
  }
  // Learning: Lq converges to the plant's, and every event is right, the first included: its
  // pairs were fitted with the commissioned Lq, and their Lq term is refitted with the curve
  // the same pairs taught before the event's estimate is formed.
  EXPECT_NEAR(learned.lq_H, 8.25e-3, 0.01 * 8.25e-3);
  for (std::size_t k = 0; k < learned.estimates.size(); ++k) {
    const EventEstimate& e = learned.estimates[k];
    ASSERT_EQ(e.outcome, EventOutcome::kPublished);
    EXPECT_NEAR(e.rs_ohm, rs, 0.003 * rs) << "event " << k;
    EXPECT_LT(e.rs_std_ohm, 0.5 * std::abs(fixed.estimates[k].rs_ohm - rs))
        << "a learned Lq is certain: event " << k;
  }
}

// The unloaded calibration of a salient machine: the friction's current alone (0.6 A here) gives
// Lq <w iq> = 8.25 mH x 300 rad/s x 0.6 A = 1.5 V, under the 2 V the threshold once was, and
// the speed loop's answer to the pulses' reluctance torque still carries the commissioned Lq's
// error into Rs (on the salient benchmark its Rs0 read 1.4 % low, +6.5 C of mean error for the
// whole run: docs/estimator.md 5.1). The default threshold learns from such pairs.
TEST(InjectionScheduler, AnUnloadedSalientMachineTeachesLqAtTheDefaultThreshold) {
  const double lq_true = 8.25e-3;
  const double default_V = InjectionConfig{}.lq_learning_min_voltage_V;
  ASSERT_LT(default_V, lq_true * 300.0 * 0.6);
  const SalientRun at_default = run_salient(true, InjectionMethod::kFixedMagnitude, 0.6, Separation::kBipolar, default_V);
  const SalientRun at_2V = run_salient(true, InjectionMethod::kFixedMagnitude, 0.6, Separation::kBipolar, 2.0);
  EXPECT_DOUBLE_EQ(at_2V.lq_H, 7.425e-3) << "below the threshold nothing is learned";
  EXPECT_NEAR(at_default.lq_H, lq_true, 0.02 * lq_true);
}

// A unipolar pair's d-axis mean also holds Rs <id> (here 0.133 ohm x -5 A, 0.67 V) and Vx <Gd>,
// which Lq <w iq> is told apart from; their model errors in proportion are not in the
// measurement's variance, so Lq is learned only where its term is at least theirs (a bipolar
// pair's are about 0). On the 30 mOhm IPM under fixed-magnitude unipolar, learning from every
// pair over 1 V taught a saturation curve (b) of 0.37 mH against a secant of 0.47 mH and read
// 31 C RMS (docs/estimator.md 5.1). With no volts threshold, at 0.25 A (Lq <w iq> 0.62 V) the
// bipolar pairs teach Lq and the unipolar ones do not; at 4 A (9.9 V) both do.
TEST(InjectionScheduler, AUnipolarPairTeachesLqOnlyWhereItsTermStandsOut) {
  const double lq_true = 8.25e-3;
  constexpr auto kFm = InjectionMethod::kFixedMagnitude;
  const SalientRun bipolar = run_salient(true, kFm, 0.25, Separation::kBipolar, 0.0);
  EXPECT_NEAR(bipolar.lq_H, lq_true, 0.03 * lq_true);
  const SalientRun unipolar = run_salient(true, kFm, 0.25, Separation::kUnipolar, 0.0);
  EXPECT_DOUBLE_EQ(unipolar.lq_H, 7.425e-3);
  const SalientRun loaded = run_salient(true, kFm, 4.0, Separation::kUnipolar, 0.0);
  EXPECT_NEAR(loaded.lq_H, lq_true, 0.04 * lq_true);
}

// The same machine with fixed-angle pulses: the event's estimate is the sample fit over its
// pairs' sums (Eq. 22), whose Lq terms are refitted to first order (sum dId y / sum dId^2).
// Fixed-angle pulses teach Lq less exactly (their <id> is not zero: here it settles 2.7 % low),
// so the later events keep that error; the first, whose pairs were fitted with the commissioned
// Lq (10 % low), is refitted with the curve its pairs taught and reads like the later ones.
TEST(InjectionScheduler, FixedAnglePairsOnASalientMachineAreRefittedWithTheLearnedLq) {
  const double rs = PlantModel{}.rs_ohm;
  const SalientRun fixed = run_salient(false, InjectionMethod::kFixedAngle);
  const SalientRun learned = run_salient(true, InjectionMethod::kFixedAngle);
  ASSERT_GE(learned.estimates.size(), 3U);
  ASSERT_EQ(learned.estimates.size(), fixed.estimates.size());
  EXPECT_NEAR(learned.lq_H, 8.25e-3, 0.04 * 8.25e-3);
  ASSERT_EQ(fixed.estimates.front().outcome, EventOutcome::kPublished);
  double later_error = 0.0;
  for (std::size_t k = 1; k < learned.estimates.size(); ++k) {
    ASSERT_EQ(learned.estimates[k].outcome, EventOutcome::kPublished);
    later_error = std::max(later_error, std::abs(learned.estimates[k].rs_ohm - rs));
  }
  const double first_error = std::abs(learned.estimates.front().rs_ohm - rs);
  const double first_error_commissioned = std::abs(fixed.estimates.front().rs_ohm - rs);
  EXPECT_GT(first_error_commissioned, 2.0 * later_error) << "the commissioned Lq biases a fixed-angle pair";
  EXPECT_LT(first_error, 1.5 * later_error) << "the first event refitted like the later ones";
}

TEST(InjectionScheduler, StandstillRecordsOverTime) {
  InjectionConfig c = test_config();
  Harness h(c, 0.0);
  h.plant.kd6 = 0.0;
  h.plant.kq6 = 0.0;
  h.run_until(0.5);
  const std::vector<P> pair = {P::kRampUp, P::kSettle, P::kRecord1, P::kRampDown, P::kRampUp,
                               P::kSettle, P::kRecord2, P::kRampDown, P::kIdle};
  std::vector<P> expected = {P::kIdle};
  expected.insert(expected.end(), pair.begin(), pair.end());
  expected.insert(expected.end(), pair.begin(), pair.end());
  EXPECT_EQ(h.phase_runs(), expected);
  for (const PhaseRun& r : runs_of(h)) {
    if (r.phase == P::kRecord1) {
      EXPECT_NEAR(static_cast<double>(r.length) * kPeriod, c.record_time_s, 2.5 * kPeriod);
    }
  }
  ASSERT_EQ(h.estimates.size(), 1U);
  ASSERT_EQ(h.pairs.size(), 2U);
  EXPECT_TRUE(h.pairs[0].time_based);
  EXPECT_EQ(h.estimates[0].outcome, EventOutcome::kPublished);
  EXPECT_NEAR(h.estimates[0].rs_ohm, h.plant.rs_ohm, 2e-4);
  EXPECT_FALSE(h.estimates[0].has_emf);
  // At rest the next event repeats this one's error (one angle, one bridge sign pattern): the
  // whole error bar is shared, so the filter's band cannot fuse it away.
  EXPECT_GT(h.estimates[0].rs_std_ohm, 0.0);
  EXPECT_EQ(h.estimates[0].rs_systematic_std_ohm, h.estimates[0].rs_std_ohm);
  // Turning, the events see the bridge's pattern at every angle: only the model's part is shared.
  Harness turning(test_config(), 300.0);
  turning.motoring_A = {0.0, 10.0};
  turning.run_until(0.5);
  ASSERT_GE(turning.estimates.size(), 1U);
  EXPECT_EQ(turning.estimates[0].outcome, EventOutcome::kPublished);
  EXPECT_LT(turning.estimates[0].rs_systematic_std_ohm, turning.estimates[0].rs_std_ohm);
}

// At rest the current sensors' gain mismatch is not averaged over a turn: a time-based event's
// error bar carries sigma / sqrt(6) of Rs for independent per-phase gain errors of sigma (the
// variance of (1/3) sum_k g_k cos(2 theta_k) over the phases' errors, at any angle); a turning
// event's whole-turn pairs average it out and do not.
TEST(InjectionScheduler, AtRestTheCurrentSensorsGainMismatchWidensTheErrorBar) {
  const auto standstill = [](double gain_std) {
    InjectionConfig c = test_config();
    c.current_gain_std_fraction = gain_std;
    Harness h(c, 0.0);
    h.plant.kd6 = 0.0;
    h.plant.kq6 = 0.0;
    h.run_until(0.5);
    return h.estimates;
  };
  const std::vector<EventEstimate> matched = standstill(0.0);
  const std::vector<EventEstimate> mismatched = standstill(0.03);
  ASSERT_EQ(matched.size(), 1U);
  ASSERT_EQ(mismatched.size(), 1U);
  EXPECT_EQ(mismatched[0].rs_ohm, matched[0].rs_ohm);  // the same measurement
  const double gain_ohm = matched[0].rs_ohm * 0.03 / std::sqrt(6.0);
  EXPECT_NEAR(mismatched[0].rs_std_ohm * mismatched[0].rs_std_ohm,
              matched[0].rs_std_ohm * matched[0].rs_std_ohm + gain_ohm * gain_ohm, 1e-6 * gain_ohm * gain_ohm);
  EXPECT_EQ(mismatched[0].rs_systematic_std_ohm, mismatched[0].rs_std_ohm);  // one angle: shared by the stop

  const auto turning = [](double gain_std) {
    InjectionConfig c = test_config();
    c.current_gain_std_fraction = gain_std;
    Harness h(c, 300.0);
    h.motoring_A = {0.0, 10.0};
    h.run_until(0.5);
    return h.estimates;
  };
  const std::vector<EventEstimate> turning_matched = turning(0.0);
  const std::vector<EventEstimate> turning_mismatched = turning(0.03);
  ASSERT_GE(turning_matched.size(), 1U);
  ASSERT_EQ(turning_mismatched.size(), turning_matched.size());
  EXPECT_EQ(turning_mismatched[0].rs_std_ohm, turning_matched[0].rs_std_ohm);
}

// The controller leaves a period's sample unbuilt when records() is false: the scheduler must
// then behave exactly as if it had been given, for every method, separation and phase.
TEST(InjectionScheduler, ReadsASampleOnlyWhenItSaysItRecords) {
  struct Case {
    const char* name;
    InjectionMethod method;
    Separation separation;
    double omega_e;
    Dq motoring;
  };
  const Case cases[] = {
      {"fixed-magnitude bipolar", InjectionMethod::kFixedMagnitude, Separation::kBipolar, 300.0, {0.0, 10.0}},
      {"fixed-magnitude unipolar", InjectionMethod::kFixedMagnitude, Separation::kUnipolar, 300.0, {0.0, 10.0}},
      {"fixed-angle bipolar", InjectionMethod::kFixedAngle, Separation::kBipolar, 300.0, {0.0, 10.0}},
      {"fixed-angle unipolar", InjectionMethod::kFixedAngle, Separation::kUnipolar, 300.0, {0.0, 10.0}},
      {"DC at standstill", InjectionMethod::kDc, Separation::kBipolar, 0.0, {}},
      {"field weakening", InjectionMethod::kFixedMagnitude, Separation::kBipolar, 1000.0, {0.0, 20.0}},
  };
  for (const Case& k : cases) {
    InjectionConfig c = test_config();
    c.method = k.method;
    c.separation = k.separation;
    Harness always(c, k.omega_e);
    Harness lazy(c, k.omega_e);
    lazy.sample_only_when_recording = true;
    for (Harness* h : {&always, &lazy}) {
      h->motoring_A = k.motoring;
      // The drive disabled for 5 ms inside the first event: its pair in progress aborts.
      h->hook = [](Harness& x) { x.enabled = !(x.time_s >= 0.03 && x.time_s < 0.035); };
      h->run_until(1.6);
    }
    ASSERT_EQ(always.records.size(), lazy.records.size()) << k.name;
    std::size_t recording_steps = 0;
    for (std::size_t n = 0; n < always.records.size(); ++n) {
      const SchedulerOutput& a = always.records[n].out;
      const SchedulerOutput& b = lazy.records[n].out;
      ASSERT_EQ(a.phase, b.phase) << k.name << " step " << n;
      ASSERT_EQ(a.injection_A.d, b.injection_A.d) << k.name << " step " << n;
      ASSERT_EQ(a.injection_A.q, b.injection_A.q) << k.name << " step " << n;
      recording_steps += a.phase == P::kRecord1 || a.phase == P::kRecord2 || a.phase == P::kPulseWait ? 1U : 0U;
    }
    EXPECT_GT(recording_steps, 100U) << k.name << ": the case must record";
    ASSERT_EQ(always.pairs.size(), lazy.pairs.size()) << k.name;
    ASSERT_GE(always.pairs.size(), 2U) << k.name;
    // A pair was in progress when the drive was disabled, and the disabled drive dropped it.
    bool busy_before = false;
    bool idle_during = true;
    for (const StepRecord& r : always.records) {
      if (r.time_s < 0.03 && r.time_s >= 0.0299) busy_before = r.out.phase != P::kIdle;
      if (r.time_s >= 0.0301 && r.time_s < 0.035) idle_during = idle_during && r.out.phase == P::kIdle;
    }
    EXPECT_TRUE(busy_before && idle_during) << k.name << ": the disabled drive must abort a pair";
    for (std::size_t n = 0; n < always.pairs.size(); ++n) {
      EXPECT_EQ(always.pairs[n].outcome, lazy.pairs[n].outcome) << k.name << " pair " << n;
      EXPECT_EQ(always.pairs[n].rs_ohm, lazy.pairs[n].rs_ohm) << k.name << " pair " << n;
      EXPECT_EQ(always.pairs[n].samples, lazy.pairs[n].samples) << k.name << " pair " << n;
    }
    ASSERT_EQ(always.estimates.size(), lazy.estimates.size()) << k.name;
    for (std::size_t n = 0; n < always.estimates.size(); ++n) {
      EXPECT_EQ(always.estimates[n].rs_ohm, lazy.estimates[n].rs_ohm) << k.name << " estimate " << n;
    }
  }
}

// ---- budget ----

// Largest F with |v0 + s F u| <= limit (Eq. 29 at the operating point), computed here; v0 is
// Eq. 3's motoring voltage, or `motoring_V` when given.
double voltage_budget(double omega_e, const Dq& im, double limit_V, const InjectionConfig& c, double s,
                      std::optional<Dq> motoring_V = std::nullopt) {
  // k = max |dB2/dt| Tw by dense sampling of Eq. 24's derivative.
  double k = 0.0;
  for (int n = 0; n <= 200000; ++n) {
    const double x = -1.0 + 2.0 * n / 200000.0;
    k = std::max(k, std::abs(0.5 * kPi * std::sin(kPi * x) - 0.25 * kPi * std::sin(2.0 * kPi * x)));
  }
  const double rs = c.rs_nominal_ohm;
  const Dq v0 = motoring_V.value_or(
      Dq{rs * im.d - omega_e * c.lq_H * im.q, rs * im.q + omega_e * (c.ld_H * im.d + c.flux_linkage_Wb)});
  const double ud = s * std::hypot(k * c.ld_H / c.tw_s, rs);
  const double uq = s * omega_e * c.ld_H;
  // Bisection on F (monotone beyond the vertex; v0 is inside the circle).
  auto inside = [&](double f) { return std::hypot(v0.d + f * ud, v0.q + f * uq) <= limit_V; };
  double lo = 0.0, hi = 1e4;
  for (int it = 0; it < 200; ++it) {
    const double mid = 0.5 * (lo + hi);
    (inside(mid) ? lo : hi) = mid;
  }
  return lo;
}

TEST(InjectionBudget, CurrentLimitReducesFForTheWorstPolarity) {
  InjectionConfig c = test_config();
  InjectionScheduler s(c, kPeriod, 64);
  SchedulerInput in;
  in.omega_e_rad_s = 300.0;
  in.current_limit_A = 80.0;
  in.motoring_ref_A = {0.0, 78.0};
  // |(+-F, 78)| <= 80  ->  F <= sqrt(80^2 - 78^2).
  InjectionScheduler::Budget b = s.budget(in, c.tw_s, 25.0);
  EXPECT_NEAR(b.f_A, std::sqrt(80.0 * 80.0 - 78.0 * 78.0), 1e-9);
  EXPECT_EQ(b.limiting, PairOutcome::kAccepted);  // still above F_min
  // A derated limit from the drive applies when it is the smaller one.
  in.current_limit_A = 79.0;
  b = s.budget(in, c.tw_s, 25.0);
  EXPECT_NEAR(b.f_A, std::sqrt(79.0 * 79.0 - 78.0 * 78.0), 1e-9);
  // Field weakening current: bipolar takes the worse polarity, here +F (towards +id).
  in.current_limit_A = 80.0;
  in.motoring_ref_A = {10.0, 70.0};
  b = s.budget(in, c.tw_s, 50.0);
  EXPECT_NEAR(b.f_A, std::sqrt(80.0 * 80.0 - 70.0 * 70.0) - 10.0, 1e-9);
  // Below F_min: skipped for the current limit.
  in.motoring_ref_A = {-10.0, 79.5};
  b = s.budget(in, c.tw_s, 25.0);
  EXPECT_EQ(b.f_A, 0.0);
  EXPECT_EQ(b.limiting, PairOutcome::kRejectedCurrentLimit);
  // Unipolar -F only needs room towards -id: with id = +10 there is plenty.
  InjectionConfig u = c;
  u.separation = Separation::kUnipolar;
  InjectionScheduler su(u, kPeriod, 64);
  in.motoring_ref_A = {10.0, 79.5};
  b = su.budget(in, c.tw_s, 25.0);
  EXPECT_NEAR(b.f_A, std::sqrt(80.0 * 80.0 - 79.5 * 79.5) + 10.0, 1e-9);
  // The configured limit applies when it is the smaller one.
  InjectionConfig low = c;
  low.current_limit_A = 60.0;
  InjectionScheduler sl(low, kPeriod, 64);
  in.motoring_ref_A = {0.0, 50.0};
  EXPECT_NEAR(sl.budget(in, c.tw_s, 50.0).f_A, std::sqrt(60.0 * 60.0 - 50.0 * 50.0), 1e-9);
}

TEST(InjectionBudget, RotatingInjectionTakesTheWorstDirection) {
  InjectionConfig c = test_config();
  c.method = InjectionMethod::kFixedAngle;
  InjectionScheduler s(c, kPeriod, 64);
  SchedulerInput in;
  in.omega_e_rad_s = 100.0;
  in.motoring_ref_A = {-30.0, 40.0};
  EXPECT_NEAR(s.budget(in, c.tw_s, 50.0).f_A, 80.0 - 50.0, 1e-9);
}

TEST(InjectionBudget, ReluctanceTorqueBudgetOnASalientMachine) {
  // Tem = 3/2 p (Ld - Lq) id iq: an injection F at iq = 40 A makes 3/2 * 3 * 2.75 mH * 40 A
  // = 0.495 Nm per ampere of F.
  InjectionConfig c = test_config();
  c.ld_H = 5.5e-3;
  c.lq_H = 8.25e-3;
  c.max_torque_disturbance_Nm = 4.0;
  InjectionScheduler s(c, kPeriod, 64);
  SchedulerInput in;
  in.omega_e_rad_s = 100.0;
  in.motoring_ref_A = {0.0, 40.0};
  const double per_amp = 1.5 * 3.0 * (8.25e-3 - 5.5e-3) * 40.0;
  InjectionScheduler::Budget b = s.budget(in, c.tw_s, 25.0);
  EXPECT_NEAR(b.f_A, 4.0 / per_amp, 1e-9);
  EXPECT_EQ(b.limiting, PairOutcome::kAccepted);
  InjectionConfig tight = c;
  tight.max_torque_disturbance_Nm = 2.0;  // 4.04 A < F_min
  InjectionScheduler st(tight, kPeriod, 64);
  b = st.budget(in, c.tw_s, 25.0);
  EXPECT_NEAR(b.f_A, 2.0 / per_amp, 1e-9);
  EXPECT_EQ(b.limiting, PairOutcome::kSkippedTorqueDisturbance);
  // No motoring current, no reluctance torque: the full F.
  in.motoring_ref_A = {0.0, 0.0};
  EXPECT_EQ(st.budget(in, c.tw_s, 25.0).f_A, 25.0);
  // Budget off (0): not limited by torque.
  InjectionConfig off = c;
  off.max_torque_disturbance_Nm = 0.0;
  InjectionScheduler so(off, kPeriod, 64);
  in.motoring_ref_A = {0.0, 40.0};
  EXPECT_EQ(so.budget(in, c.tw_s, 25.0).f_A, 25.0);
}

// The configured pair's own voltage budget (no field-weakening pairs), its operating point, and
// the F that both polarities allow for 25 A wanted (voltage_budget).
InjectionConfig configured_pair_config() {
  InjectionConfig c = test_config();
  c.field_weakening_pairs = false;
  return c;
}

SchedulerInput voltage_budget_input(double omega_e) {
  SchedulerInput in;
  in.voltage_limit_V = 356.0;
  in.motoring_ref_A = {0.0, 20.0};
  in.omega_e_rad_s = omega_e;
  return in;
}

double expected_voltage_f(const SchedulerInput& in, const InjectionConfig& c, std::optional<Dq> motoring_V = std::nullopt) {
  const double limit = in.voltage_limit_V - c.headroom_margin_V;
  return std::min({25.0, voltage_budget(in.omega_e_rad_s, in.motoring_ref_A, limit, c, 1.0, motoring_V),
                   voltage_budget(in.omega_e_rad_s, in.motoring_ref_A, limit, c, -1.0, motoring_V)});
}

TEST(InjectionBudget, VoltageHeadroomReducesFAtSpeed) {
  const InjectionConfig c = configured_pair_config();
  InjectionScheduler s(c, kPeriod, 64);
  SchedulerInput in = voltage_budget_input(0.0);
  for (double w : {300.0, 900.0, 980.0, 1000.0}) {
    in.omega_e_rad_s = w;
    const double expected = expected_voltage_f(in, c);
    const InjectionScheduler::Budget b = s.budget(in, c.tw_s, 25.0);
    EXPECT_NEAR(b.f_A, expected, 1e-3) << "w " << w;
    if (expected < c.f_min_A) {
      EXPECT_EQ(b.limiting, PairOutcome::kRejectedVoltageHeadroom) << "w " << w;
    } else {
      EXPECT_EQ(b.limiting, PairOutcome::kAccepted) << "w " << w;
    }
  }
  // At 1000 rad/s the motoring voltage alone is close to the limit: F must be small.
  in.omega_e_rad_s = 1000.0;
  EXPECT_LT(s.budget(in, c.tw_s, 25.0).f_A, c.f_min_A);
}

// The machine needs what the current loop commands, not what the commissioned model says: given
// the loop's mean command (and its mean square), the budget takes it as the motoring voltage,
// lengthened by twice its spread. Given for another period, it is not used.
TEST(InjectionBudget, TheLoopsMotoringVoltageReplacesTheModels) {
  const InjectionConfig c = configured_pair_config();
  InjectionScheduler s(c, kPeriod, 64);
  SchedulerInput in = voltage_budget_input(900.0);
  in.time_s = 3.0;
  const Dq im = in.motoring_ref_A;
  auto expected = [&](std::optional<Dq> v0) { return expected_voltage_f(in, c, v0); };
  const double model_f = s.budget(in, c.tw_s, 25.0).f_A;
  ASSERT_NEAR(model_f, expected(std::nullopt), 1e-3);
  const double rs = c.rs_nominal_ohm;
  const Dq model{rs * im.d - in.omega_e_rad_s * c.lq_H * im.q,
                 rs * im.q + in.omega_e_rad_s * (c.ld_H * im.d + c.flux_linkage_Wb)};
  // The machine needs 12 V more on q than the model (a bridge error, a Ke commissioned low).
  const Dq measured{model.d, model.q + 12.0};
  s.set_motoring_voltage(in.time_s, measured, measured.d * measured.d + measured.q * measured.q);
  const double f = s.budget(in, c.tw_s, 25.0).f_A;
  EXPECT_NEAR(f, expected(measured), 1e-3);
  EXPECT_LT(f, model_f - 1.0);
  // A spread of 4 V about the mean: the mean lengthened by 8 V.
  const double mean_sq = measured.d * measured.d + measured.q * measured.q;
  s.set_motoring_voltage(in.time_s, measured, mean_sq + 16.0);
  const double scale = 1.0 + 8.0 / std::sqrt(mean_sq);
  EXPECT_NEAR(s.budget(in, c.tw_s, 25.0).f_A, expected(Dq{scale * measured.d, scale * measured.q}), 1e-3);
  // Given for the period before: the model's.
  in.time_s += kPeriod;
  EXPECT_NEAR(s.budget(in, c.tw_s, 25.0).f_A, model_f, 1e-9);
}

// At the voltage limit (the motoring point alone needs more than limit - margin) no level of
// the configured pair fits; two levels that weaken the field do, and each lies inside the
// worst-case voltage of the Eq. 29 budget.
TEST(InjectionBudget, FieldWeakeningPairAtTheVoltageLimit) {
  InjectionConfig c = test_config();
  InjectionScheduler s(c, kPeriod, 64);
  SchedulerInput in;
  in.voltage_limit_V = 356.0;
  in.motoring_ref_A = {0.0, 20.0};
  in.omega_e_rad_s = 1000.0;
  const double limit = in.voltage_limit_V - c.headroom_margin_V;
  const Dq im = in.motoring_ref_A;
  const double rs = c.rs_nominal_ohm;
  const Dq v0{rs * im.d - in.omega_e_rad_s * c.lq_H * im.q,
              rs * im.q + in.omega_e_rad_s * (c.ld_H * im.d + c.flux_linkage_Wb)};
  ASSERT_GT(std::hypot(v0.d, v0.q), limit) << "the operating point must sit at the limit";
  // Worst case of a level -F (Eq. 29's steepest edge and the q-axis term together).
  const InjectionCurrentRange range = injection_current_range_at_operating_point_A(
      InjectionHeadroomInput{rs, c.ld_H, c.lq_H, c.flux_linkage_Wb, in.omega_e_rad_s, im.d, im.q, limit, c.tw_s, c.window},
      -1.0);
  ASSERT_TRUE(range.valid);
  const double per_amp_d = required_injection_voltage_V(1.0, c.ld_H, rs, c.tw_s, c.window);
  auto worst = [&](double f) { return std::hypot(v0.d - f * per_amp_d, v0.q - f * in.omega_e_rad_s * c.ld_H); };

  const InjectionScheduler::Budget b = s.budget(in, c.tw_s, 25.0);
  EXPECT_TRUE(b.field_weakening);
  EXPECT_EQ(b.limiting, PairOutcome::kAccepted);
  EXPECT_LE(worst(b.low_A), limit + 1e-6);
  EXPECT_LE(worst(b.f_A), limit + 1e-6);
  EXPECT_GT(worst(0.9 * range.lo_A), limit) << "the lower level is what comes off the limit";
  EXPECT_GE(b.low_A, c.field_weakening_low_fraction * b.f_A - 1e-12);
  EXPECT_GE(b.f_A - b.low_A, c.f_min_A);
  EXPECT_LE(b.f_A, 25.0);

  // Turning the other way: -F still lowers the voltage (w Ld F and the EMF change sign
  // together), and the pair is the same.
  SchedulerInput reverse = in;
  reverse.omega_e_rad_s = -in.omega_e_rad_s;
  reverse.motoring_ref_A = {0.0, -20.0};
  const InjectionScheduler::Budget rb = s.budget(reverse, c.tw_s, 25.0);
  EXPECT_TRUE(rb.field_weakening);
  EXPECT_NEAR(rb.f_A, b.f_A, 1e-9);
  EXPECT_NEAR(rb.low_A, b.low_A, 1e-9);

  // Not for fixed-angle injection, not at time-based speeds, not when switched off.
  InjectionConfig fa = c;
  fa.method = InjectionMethod::kFixedAngle;
  EXPECT_FALSE(InjectionScheduler(fa, kPeriod, 64).budget(in, c.tw_s, 25.0).field_weakening);
  InjectionConfig off = c;
  off.field_weakening_pairs = false;
  const InjectionScheduler::Budget none = InjectionScheduler(off, kPeriod, 64).budget(in, c.tw_s, 25.0);
  EXPECT_FALSE(none.field_weakening);
  EXPECT_EQ(none.limiting, PairOutcome::kRejectedVoltageHeadroom);
  // With the whole current limit taken by the motoring current nothing fits either way.
  in.motoring_ref_A = {0.0, 79.0};
  const InjectionScheduler::Budget full = s.budget(in, c.tw_s, 25.0);
  EXPECT_LT(full.f_A, c.f_min_A);
  EXPECT_FALSE(full.field_weakening);
}

// The range of F inside the limit: from zero when the motoring point has room, from the level
// that comes off the limit when it has none, empty when no F fits.
TEST(InjectionBudget, CurrentRangeAtTheOperatingPoint) {
  InjectionHeadroomInput h;
  h.omega_e_rad_s = 300.0;
  h.iq_A = 20.0;
  h.voltage_limit_V = 341.0;
  const InjectionCurrentRange inside = injection_current_range_at_operating_point_A(h, -1.0);
  ASSERT_TRUE(inside.valid);
  EXPECT_EQ(inside.lo_A, 0.0);
  // The upper end is the largest F of one polarity.
  EXPECT_NEAR(inside.hi_A, max_injection_current_at_operating_point_A(h, -1.0), 1e-9);

  h.omega_e_rad_s = 1000.0;  // the motoring point alone beyond the limit
  const Dq v0 = motoring_voltage(h);
  ASSERT_GT(std::hypot(v0.d, v0.q), h.voltage_limit_V);
  const InjectionCurrentRange limit = injection_current_range_at_operating_point_A(h, -1.0);
  ASSERT_TRUE(limit.valid);
  EXPECT_GT(limit.lo_A, 0.0);
  const double per_amp_d = -required_injection_voltage_V(1.0, h.ld_H, h.rs_ohm, h.tw_s, h.window);
  const double per_amp_q = -h.omega_e_rad_s * h.ld_H;
  for (double f : {limit.lo_A, limit.hi_A}) {
    EXPECT_NEAR(std::hypot(v0.d + f * per_amp_d, v0.q + f * per_amp_q), h.voltage_limit_V, 1e-6) << f;
  }
  // +F raises the voltage there: nothing fits. Nor at a limit far below the EMF.
  EXPECT_FALSE(injection_current_range_at_operating_point_A(h, 1.0).valid);
  h.voltage_limit_V = 10.0;
  EXPECT_FALSE(injection_current_range_at_operating_point_A(h, -1.0).valid);
  h.voltage_limit_V = std::nan("");
  EXPECT_FALSE(injection_current_range_at_operating_point_A(h, -1.0).valid);
}

// The pair itself: recording 1 at -low F, one ramp straight to -F (never through zero, which
// would put the drive back on the voltage limit), recording 2 at -F, then back to zero. Its
// estimate carries the sign pattern's shared error.
TEST(InjectionScheduler, FieldWeakeningPairRecordsAtTwoNegativeLevels) {
  InjectionConfig c = test_config();
  c.vx_initial_V = 1.5;  // the harness plant's bridge, known
  c.vx_initial_std_V = 0.01;
  Harness h(c, 1000.0);
  h.motoring_A = {0.0, 20.0};
  h.run_until(1.0);  // its recordings last field_weakening_record_min_time_s each
  ASSERT_GE(h.pairs.size(), 1U);
  const PairResult& p = h.pairs[0];
  ASSERT_TRUE(p.field_weakening);
  EXPECT_GE(static_cast<double>(p.samples) * kPeriod, c.field_weakening_record_min_time_s - 1e-9);
  for (const PairResult& q : h.pairs) {
    EXPECT_TRUE(q.field_weakening) << "every pair at this point weakens the field";
  }
  EXPECT_EQ(p.outcome, PairOutcome::kAccepted) << to_string(p.outcome);
  EXPECT_GE(p.low_level, c.field_weakening_low_fraction - 1e-12);
  EXPECT_LT(p.low_level, 1.0);
  bool seen_record1 = false;
  bool seen_record2 = false;
  bool between = false;
  for (const StepRecord& r : h.records) {
    if (r.time_s > p.time_s) break;
    EXPECT_LE(r.out.injection_A.d, 1e-12) << "t " << r.time_s;
    if (r.out.phase == SchedulerPhase::kRecord1) {
      seen_record1 = true;
      EXPECT_NEAR(r.out.injection_A.d, -p.low_level * p.f_A, 1e-9);
    }
    if (seen_record1 && !seen_record2 && r.out.phase != SchedulerPhase::kRecord1) between = true;
    if (between && r.out.phase != SchedulerPhase::kRecord2 && !seen_record2) {
      EXPECT_LE(r.out.injection_A.d, -p.low_level * p.f_A + 1e-9) << "t " << r.time_s;
    }
    if (r.out.phase == SchedulerPhase::kRecord2) {
      seen_record2 = true;
      EXPECT_NEAR(r.out.injection_A.d, -p.f_A, 1e-9);
    }
  }
  EXPECT_TRUE(seen_record1 && seen_record2);
  EXPECT_NEAR(p.rs_ohm, h.plant.rs_ohm, 3.0 * p.rs_std_ohm + 1e-3);
  ASSERT_GE(h.estimates.size(), 1U);
  EXPECT_EQ(h.estimates[0].outcome, EventOutcome::kPublished);
  EXPECT_GT(h.estimates[0].rs_systematic_std_ohm, 0.0);
  EXPECT_LE(h.estimates[0].rs_systematic_std_ohm, h.estimates[0].rs_std_ohm);
}

// At the voltage limit the field-weakening pair measures the magnet too: both its levels are
// negative (<id> about -0.65 F), so with the commissioned Ld 10 % below the machine's its Ke
// would read 2.7 % low (0.55 mH x 1000 rad/s x 16 A / 333 rad/s); it solves Ld from its two
// levels instead.
TEST(InjectionScheduler, FieldWeakeningPairMeasuresKeWithItsOwnLd) {
  InjectionConfig c = test_config();
  c.vx_initial_V = 1.5;
  c.vx_initial_std_V = 0.01;
  Harness h(c, 1000.0);
  h.plant.ld_H = 1.1 * c.ld_H;
  h.motoring_A = {0.0, 20.0};
  h.run_until(1.0);
  ASSERT_GE(h.pairs.size(), 1U);
  ASSERT_TRUE(h.pairs[0].field_weakening);
  ASSERT_GE(h.estimates.size(), 1U);
  ASSERT_EQ(h.estimates[0].outcome, EventOutcome::kPublished);
  ASSERT_TRUE(h.estimates[0].has_emf);
  EXPECT_NEAR(h.estimates[0].ke_V_s_per_rad, h.plant.ke_V_s_per_rad, 5e-4);
}

// A saturating q-axis: the speed loop answers each pulse's reluctance torque with iq moving in
// proportion to the injection (diq = 0.15 dId, the 30 mohm machine's figure), so the fit's
// Lq d(w iq) term needs the incremental Lq at the load, which is below the secant the pairs'
// means measure. Pairs at a light and a heavy load learn the curve (a - b u); the loaded
// pairs then read Rs right. With one Lq for every load (lq_saturation_std_fraction = 0) they
// read it far off.
InjectionConfig saturation_test_config() {
  InjectionConfig c = test_config();
  c.vx_initial_V = 1.5;
  c.vx_initial_std_V = 0.01;
  c.max_load_change_A = 20.0;  // the iq answer is what these tests are about
  c.rs_max_ohm = 0.5;
  c.rs_min_ohm = 0.02;
  return c;
}

// The speed loop's answer to the pulses' reluctance torque: iq moves by 0.15 A per ampere of
// injection on top of the load's iq0.
void answer_the_reluctance_torque(Harness& h, const double* iq0) {
  h.hook = [iq0](Harness& x) {
    const double inj = x.records.empty() ? 0.0 : x.records.back().out.injection_A.d;
    x.motoring_A = {0.0, *iq0 + 0.15 * inj};
  };
}

// The published estimates' mean relative error, from estimate `first` on (at least three).
double mean_published_rs_error(const Harness& h, std::size_t first) {
  double sum = 0.0;
  int n = 0;
  for (std::size_t k = first; k < h.estimates.size(); ++k) {
    if (h.estimates[k].outcome == EventOutcome::kPublished) {
      sum += h.estimates[k].rs_ohm;
      ++n;
    }
  }
  EXPECT_GE(n, 3);
  return n > 0 ? sum / n / h.plant.rs_ohm - 1.0 : 1.0;
}

double loaded_rs_error(double saturation_std_fraction, double* lq_a, double* lq_b) {
  InjectionConfig c = saturation_test_config();
  c.lq_saturation_std_fraction = saturation_std_fraction;
  Harness h(c);
  h.plant.lq_sat_H = 0.55e-3;  // secant 10 % lower at the current limit
  double iq0 = 5.0;
  answer_the_reluctance_torque(h, &iq0);
  h.run_until(3.0);   // light load: several events
  iq0 = 60.0;
  const std::size_t before = h.estimates.size();
  h.run_until(8.0);   // heavy load
  *lq_a = h.scheduler.lq_H();
  *lq_b = h.scheduler.lq_saturation_H();
  return mean_published_rs_error(h, before + 2);
}

// Pairs at one load whose Lq measurements differ by the level (a small level's d-axis mean 0.5 %
// of Lq <w iq> off while |id| < 15 A, which the large level's recordings never are, as the bridge's pattern left it between the spindle's two levels in unseen
// round 17, case a) and whose mean iq differs a little with the level (the speed loop answers
// the reluctance torque, 0.15 A per ampere of id, and a little more on one sign than on the
// other: 0.03 A per ampere of |id| on top, so the large level's pairs sit 0.45 A higher). Read
// as saturation, the 0.5 % over that contrast in u (0.0015) is a b of 18 mH, and pairs at one
// load drive b past any prior; the curve then extrapolates it to 60 A. Pairs within a lever in
// u of 0.05 (the default prior) of a load that taught the curve (an anchor) are taken at its u:
// b learns only from loads that far apart, and there, on this plant (no saturation), it stays near zero and the loaded
// Rs is right.
TEST(InjectionScheduler, PairsAtOneLoadTeachNoSaturation) {
  InjectionConfig c = saturation_test_config();
  Harness h(c);
  h.plant.small_id_A = 15.0;  // the level 0.4 (10 A) below it, the level 1 (25 A) above
  h.plant.small_id_vd_V = -0.005 * h.plant.lq_H * h.omega_e_rad_s * 10.0;  // 0.5 % of Lq w iq at 10 A
  double iq0 = 10.0;
  h.hook = [&iq0](Harness& x) {
    const double inj = x.records.empty() ? 0.0 : x.records.back().out.injection_A.d;
    x.motoring_A = {0.0, iq0 + 0.15 * inj + 0.03 * std::abs(inj)};
  };
  h.run_until(20.0);  // 40 events at the light load
  EXPECT_FALSE(h.scheduler.lq_saturation_resolved());
  EXPECT_LT(std::abs(h.scheduler.lq_saturation_H()), 0.02e-3) << "loads 0.45 A apart are no lever";
  EXPECT_NEAR(h.scheduler.lq_secant_H(10.5), 5.5e-3, 0.04e-3) << "the secant between the levels' two readings";
  iq0 = 60.0;
  const std::size_t before = h.estimates.size();
  h.run_until(26.0);
  EXPECT_LT(std::abs(h.scheduler.lq_secant_H(60.0) - 5.5e-3), 0.1e-3) << "the loaded pairs teach the curve";
  // (Without the lever +74 %. With it about 1 %: the quarter per cent the small level left in a
  // at the light load, over the lever, comes back tripled in the incremental a - 3 b u.)
  EXPECT_LT(std::abs(mean_published_rs_error(h, before + 2)), 0.02);
  // A long spell back at the light load (600 pairs): its pairs stay at their anchor, so the
  // levels' contrast does not walk b again while the drift lets the filter forget the far load.
  iq0 = 10.0;
  h.run_until(176.0);
  EXPECT_LT(std::abs(h.scheduler.lq_secant_H(60.0) - 5.5e-3), 0.1e-3) << "after a long light spell";
  iq0 = 60.0;
  const std::size_t back = h.estimates.size();
  h.run_until(182.0);
  EXPECT_LT(std::abs(mean_published_rs_error(h, back + 2)), 0.02) << "loaded again";
}

// A machine whose secant falls as u^2, not u (lq_H - c u^2: the incremental lq_H - 5 c u^2), learned
// at 5 A and 60 A. The quadratic curve, a - b u, fits both secants and resolves b, but then
// draws the incremental at 60 A as a - 3 b u: the gap 2 c u^2 where the machine's is 4 c u^2,
// 0.62 mH short, and the loaded Rs reads high by about w diq x 0.62 mH / (Rs dId), over 10 %.
// A flux map of the machine (its secant at 20, 40, 60 and 80 A) gives the curve its shape;
// resolved by the same pairs, the incremental is then the machine's and the Rs within 1 %.
// The quartic machine's light load (5 A, 3 s), then its loaded point (60 A, until 8 s): the
// published estimates' mean error there. iq0 holds the load the harness's hook reads.
double light_then_loaded_rs_error(Harness& h, double loss_H, double& iq0) {
  h.plant.lq_sat_H = loss_H;
  h.plant.lq_sat_power = 2;
  iq0 = 5.0;
  answer_the_reluctance_torque(h, &iq0);
  h.run_until(3.0);
  iq0 = 60.0;
  const std::size_t before = h.estimates.size();
  h.run_until(8.0);
  return mean_published_rs_error(h, before + 2);
}

double quartic_rs_error(bool with_map, double* incremental_60_H) {
  InjectionConfig c = saturation_test_config();  // current limit 80 A, lq_H 5.5 mH
  const double loss_H = 0.55e-3 / ((60.0 / 80.0) * (60.0 / 80.0));  // the same secant at 60 A as above
  if (with_map) {
    const std::array<double, 4> currents{20.0, 40.0, 60.0, 80.0};
    for (std::size_t k = 0; k < currents.size(); ++k) {
      const double u = (currents[k] / 80.0) * (currents[k] / 80.0);
      c.lq_map.current_A[k] = currents[k];
      c.lq_map.secant_H[k] = c.lq_H - loss_H * u * u;
    }
    c.lq_map.points = static_cast<int>(currents.size());
  }
  Harness h(c);
  double iq0 = 0.0;
  const double rs_error = light_then_loaded_rs_error(h, loss_H, iq0);
  EXPECT_TRUE(h.scheduler.lq_saturation_resolved()) << "pairs at two loads resolve the curve";
  *incremental_60_H = h.scheduler.lq_incremental_H(60.0);
  return rs_error;
}

TEST(InjectionScheduler, AResolvedCurveTakesTheFluxMapsShape) {
  const double u60 = (60.0 / 80.0) * (60.0 / 80.0);
  const double true_incremental = 5.5e-3 - 5.0 * (0.55e-3 / u60) * u60 * u60;
  double incremental = 0.0;
  const double mapped = quartic_rs_error(true, &incremental);
  EXPECT_NEAR(incremental, true_incremental, 0.05e-3);
  EXPECT_LT(std::abs(mapped), 0.01) << "the map's shape, resolved by the pairs";
  const double quadratic = quartic_rs_error(false, &incremental);
  EXPECT_GT(incremental, true_incremental + 0.4e-3) << "a - 3 b u: the gap half the machine's";
  EXPECT_GT(quadratic, 0.05) << "the quadratic's gap: the loaded Rs reads high";
}

// The same quartic machine without a map, at three loads far apart (5, 35 and 60 A: u 0.004,
// 0.19 and 0.56). Two loads leave the curve a - b u and its incremental half the machine's gap
// (above); the third brings in the bend b2 u^2 (InjectionScheduler::add_bend_prior), which is
// this machine's whole saturation: the incremental at 60 A is then its own, a - 5 b2 u^2.
TEST(InjectionScheduler, AThirdLoadTeachesTheCurvesBend) {
  InjectionConfig c = saturation_test_config();
  const double u60 = (60.0 / 80.0) * (60.0 / 80.0);
  const double loss_H = 0.55e-3 / u60;  // the machine of the test above
  Harness h(c);
  double iq0 = 0.0;
  const double two_loads_rs_error = light_then_loaded_rs_error(h, loss_H, iq0);
  const double two_loads = h.scheduler.lq_incremental_H(60.0);
  EXPECT_EQ(h.scheduler.lq_bend_H(), 0.0) << "two anchors: no bend";
  // The third load's first events: its pairs teach the bend, and the first two loads' secants stay
  // (the bend enters with every slope that keeps them, InjectionScheduler::add_bend_prior).
  const double secant_5_H = h.scheduler.lq_secant_H(5.0);
  const double secant_60_H = h.scheduler.lq_secant_H(60.0);
  iq0 = 35.0;
  h.run_until(h.time_s + 1.0);
  EXPECT_NEAR(h.scheduler.lq_bend_H(), loss_H, 0.3 * loss_H) << "the third load's own pairs";
  EXPECT_NEAR(h.scheduler.lq_secant_H(5.0), secant_5_H, 0.02e-3);
  EXPECT_NEAR(h.scheduler.lq_secant_H(60.0), secant_60_H, 0.02e-3);
  // The three loads in turn: the learner's drift (0.2 % of Lq a pair, on each of
  // a, b and b2) forgets a load it has not seen for a while, and three parameters want three
  // loads seen lately.
  for (int cycle = 0; cycle < 3; ++cycle) {
    const double t0 = h.time_s;
    iq0 = 35.0;
    h.run_until(t0 + 3.0);
    iq0 = 5.0;
    h.run_until(t0 + 6.0);
    iq0 = 60.0;
    h.run_until(t0 + 9.0);
  }
  const std::size_t before = h.estimates.size();
  h.run_until(h.time_s + 3.0);
  const double secant_35_H = 5.5e-3 - loss_H * std::pow(35.0 / 80.0, 4.0);
  const double true_incremental = 5.5e-3 - 5.0 * loss_H * u60 * u60;
  EXPECT_GT(two_loads, true_incremental + 0.4e-3);
  EXPECT_GT(two_loads_rs_error, 0.05);
  EXPECT_NEAR(h.scheduler.lq_bend_H(), loss_H, 0.25 * loss_H);
  EXPECT_NEAR(h.scheduler.lq_secant_H(35.0), secant_35_H, 0.02e-3);
  // (Within 2 % of the machine's, against 15 % with two loads: what the drift leaves.)
  EXPECT_NEAR(h.scheduler.lq_incremental_H(60.0), true_incremental, 0.1e-3);
  const double rs_error = mean_published_rs_error(h, before + 2);
  EXPECT_LT(std::abs(rs_error), 0.03);
  EXPECT_LT(std::abs(rs_error), two_loads_rs_error / 3.0);
}

TEST(InjectionScheduler, ASaturatingQAxisIsLearnedAcrossLoads) {
  double a = 0.0;
  double b = 0.0;
  const double learned = loaded_rs_error(0.2, &a, &b);
  EXPECT_NEAR(a, 5.5e-3, 0.05e-3);
  EXPECT_NEAR(b, 0.55e-3, 0.15e-3);
  EXPECT_LT(std::abs(learned), 0.01) << "loaded Rs with the saturation learned";
  const double single = loaded_rs_error(0.0, &a, &b);
  EXPECT_EQ(b, 0.0);
  EXPECT_GT(std::abs(single), 0.03) << "one Lq at every load: the loaded Rs is biased";
}

// A salient machine whose torque budget refuses every pulse under heavy load (1 N m: F at most
// 1.35 A at 60 A, below F_min) and whose q axis saturates (its secant 10 % lower at the 80 A
// limit). Pairs run at the light load only, so the curve has one anchor and the secant at 60 A
// is extrapolated from it. Listening pairs (two recordings, no pulse) measure the secant there
// from <vd> alone: the curve learns it, and the loaded point becomes an anchor. Without them
// the secant at 60 A stays at the light load's.
struct ListeningRun {
  double secant_60_H = 0.0;
  std::uint32_t listened = 0;
  std::uint32_t learned = 0;
  bool resolved = false;
  std::size_t pulses_under_load = 0;  // steps with an injection current at the heavy load
  std::size_t refused_under_load = 0;  // levels reported refused for their torque there
  double speed_gap_rad_s = 0.0;  // the first listening pair's recording 2 mean speed less recording 1's
};

// accel_e_rad_s2: from the load step on, the shaft accelerates at this rate (electrical) until
// `until_s`, the run's end.
ListeningRun listening_run(bool listening, double accel_e_rad_s2 = 0.0, double until_s = 8.0) {
  InjectionConfig c = saturation_test_config();
  c.lq_listening = listening;
  c.f_A = 10.0;
  c.f_min_A = 2.0;
  c.lq_H = 8.25e-3;
  c.max_torque_disturbance_Nm = 1.0;  // 3/2 p (Lq - Ld) F iq: F up to 16 A at 5 A, 1.35 A at 60 A
  Harness h(c);
  h.plant.lq_H = 8.25e-3;
  h.plant.lq_sat_H = 0.825e-3;
  h.scheduler.set_winding_resistance(h.plant.rs_ohm, 1e-6 * h.plant.rs_ohm * h.plant.rs_ohm);
  h.motoring_A = {0.0, 5.0};
  h.run_until(3.0);
  h.motoring_A = {0.0, 60.0};
  const auto omega_at = [accel_e_rad_s2](double t_s) { return 300.0 + accel_e_rad_s2 * (t_s - 3.0); };
  if (accel_e_rad_s2 != 0.0) {
    h.voltage_limit_V = 2000.0;  // (the speed, not the bus, is what the run is about)
    h.hook = [omega_at](Harness& x) { x.omega_e_rad_s = omega_at(x.time_s); };
  }
  const std::size_t from = h.records.size();
  h.run_until(until_s);
  ListeningRun r;
  r.secant_60_H = h.scheduler.lq_secant_H(60.0);
  r.listened = h.scheduler.lq_listening_pairs();
  r.learned = h.scheduler.lq_listening_learned();
  r.resolved = h.scheduler.lq_saturation_resolved();
  for (std::size_t k = from; k < h.records.size(); ++k) {
    const Dq& i = h.records[k].out.injection_A;
    r.pulses_under_load += (i.d != 0.0 || i.q != 0.0) ? 1U : 0U;
  }
  for (const PairResult& p : h.pairs) {
    r.refused_under_load += p.time_s >= 3.0 && p.outcome == PairOutcome::kSkippedTorqueDisturbance ? 1U : 0U;
  }
  // Under the load every recording is a listening pair's (no pulse fits): the first one's two
  // recordings, each a run of steps in its phase.
  std::array<double, 2> sum{};
  std::array<int, 2> n{};
  int recording = -1;
  for (std::size_t k = from; k < h.records.size() && recording < 2; ++k) {
    const SchedulerPhase ph = h.records[k].out.phase;
    const int which = ph == SchedulerPhase::kRecord1 ? 0 : ph == SchedulerPhase::kRecord2 ? 1 : -1;
    if (which >= 0) {
      recording = which;
      sum[static_cast<std::size_t>(which)] += omega_at(h.records[k].time_s);  // (300 when not accelerating)
      ++n[static_cast<std::size_t>(which)];
    } else if (recording == 1) {
      recording = 2;  // past the second recording
    }
  }
  if (n[0] > 0 && n[1] > 0) {
    r.speed_gap_rad_s = sum[1] / n[1] - sum[0] / n[0];
  }
  return r;
}

TEST(InjectionScheduler, ListeningPairsTeachTheCurveWhereTheTorqueBudgetRefusesPulses) {
  const double u = (60.0 / 80.0) * (60.0 / 80.0);
  const double true_secant = 8.25e-3 - 0.825e-3 * u;
  const ListeningRun on = listening_run(true);
  const ListeningRun off = listening_run(false);
  EXPECT_GE(on.learned, 1U);
  EXPECT_LE(on.listened, 2U) << "one listening pair per load that taught no anchor, not one per event";
  EXPECT_EQ(on.pulses_under_load, 0U) << "a listening pair injects nothing";
  EXPECT_EQ(on.refused_under_load, off.refused_under_load) << "the level it follows is reported refused all the same";
  EXPECT_NEAR(on.secant_60_H, true_secant, 0.005 * true_secant);
  EXPECT_TRUE(on.resolved) << "two loads far apart";
  EXPECT_GT(off.refused_under_load, 5U);
  EXPECT_EQ(off.listened, 0U);
  EXPECT_GT(off.secant_60_H - true_secant, 0.5 * 0.825e-3 * u) << "the light load's secant, extrapolated";
  EXPECT_FALSE(off.resolved);
}

// A vehicle accelerating under its load (torque mode): at 400 rad/s^2 (300 -> 700 rad/s in the
// run's last second) the speed moves by about 23 rad/s between a listening pair's recordings,
// beyond the pulses' speed-change guard (max(3 rad/s, 2 %): 6.4 rad/s there), which refused it
// until 2026-12-08; and braking at 200 rad/s^2 (300 -> 100 rad/s) by about -12 rad/s. The
// listening pair takes <vd> against <w iq> over both recordings, sample by sample, so the moving
// speed is in its regressor: it learns the secant at the load within 0.5 %.
TEST(InjectionScheduler, AListeningPairLearnsWhileTheShaftAccelerates) {
  const double u = (60.0 / 80.0) * (60.0 / 80.0);
  const double true_secant = 8.25e-3 - 0.825e-3 * u;
  for (const double accel : {400.0, -200.0}) {
    SCOPED_TRACE(accel);
    const ListeningRun r = listening_run(true, accel, 4.0);
    // The premise: the speed moved between the recordings by more than the pulses' guard.
    EXPECT_GT(std::abs(r.speed_gap_rad_s), std::max(3.0, 0.02 * 300.0));
    EXPECT_GE(r.learned, 1U);
    EXPECT_EQ(r.learned, r.listened) << "every listening pair learns";
    EXPECT_EQ(r.pulses_under_load, 0U);
    EXPECT_NEAR(r.secant_60_H, true_secant, 0.005 * true_secant);
    EXPECT_TRUE(r.resolved);
  }
}

// A listening pair gives way when the motoring point needs the voltage (release_motoring) and
// ends its event with what the event has: the pair injected nothing. Run with the levels in
// either order: the small level (4 A) passes at 20 A, the load then rises to 60 A, where the large
// one's torque (10 A) is refused and a listening pair follows.
struct GiveWayRun {
  std::vector<PairResult> pairs;
  std::vector<EventEstimate> estimates;
  bool gave_way = false;
  bool pulse_after = false;  // an injection current after the listening pair gave way
  std::uint32_t listened = 0;
};

GiveWayRun give_way_run(const std::array<double, 4>& levels, double iq_start_A) {
  InjectionConfig c = saturation_test_config();
  c.f_A = 10.0;
  c.f_min_A = 2.0;
  c.levels = levels;
  c.lq_H = 8.25e-3;
  c.max_torque_disturbance_Nm = 1.0;  // 3/2 p (Lq - Ld) F iq: 4 A fits at 20 A, 10 A does not at 60 A
  c.interval_s = 10.0;
  Harness h(c);
  h.plant.lq_H = 8.25e-3;
  h.scheduler.set_winding_resistance(h.plant.rs_ohm, 1e-6 * h.plant.rs_ohm * h.plant.rs_ohm);
  double iq0 = iq_start_A;
  GiveWayRun r;
  h.hook = [&](Harness& x) {
    if (!x.pairs.empty() && x.pairs.front().outcome == PairOutcome::kAccepted) {
      iq0 = 60.0;
    }
    x.motoring_A = {0.0, iq0};
    const StepRecord* last = x.records.empty() ? nullptr : &x.records.back();
    r.pulse_after = r.pulse_after || (r.gave_way && last != nullptr && last->out.injection_A.d != 0.0);
    // A listening pair's recording: a recording phase with no injection, at the heavy load (a
    // bipolar pair's first recording carries its pulse).
    const bool listening = last != nullptr && iq0 == 60.0 && last->out.phase == SchedulerPhase::kRecord1 &&
                           last->out.injection_A.d == 0.0;
    x.release_motoring = listening;
    r.gave_way = r.gave_way || listening;
  };
  h.run_until(1.0);
  r.pairs = h.pairs;
  r.estimates = h.estimates;
  r.listened = h.scheduler.lq_listening_pairs();
  return r;
}

TEST(InjectionScheduler, AListeningPairGivesWayWithTheEventsAcceptedPairs) {
  // The small level first: accepted at 20 A; the large one refused at 60 A; the event publishes.
  const GiveWayRun small_first = give_way_run({0.4, 1.0, 0.0, 0.0}, 20.0);
  ASSERT_TRUE(small_first.gave_way) << "a listening pair started";
  ASSERT_EQ(small_first.pairs.size(), 2U);
  EXPECT_EQ(small_first.pairs[0].outcome, PairOutcome::kAccepted);
  EXPECT_EQ(small_first.pairs[1].outcome, PairOutcome::kSkippedTorqueDisturbance);
  EXPECT_EQ(small_first.listened, 0U) << "ended before its recordings";
  ASSERT_EQ(small_first.estimates.size(), 1U);
  EXPECT_EQ(small_first.estimates[0].outcome, EventOutcome::kPublished);
  EXPECT_FALSE(small_first.pulse_after);
  // The large level first, at 60 A from the start: refused, listened to, given way; the small
  // level does not start after it (its pair would need the voltage the motoring point asked for).
  const GiveWayRun large_first = give_way_run({1.0, 0.4, 0.0, 0.0}, 60.0);
  ASSERT_TRUE(large_first.gave_way);
  ASSERT_EQ(large_first.pairs.size(), 1U);
  EXPECT_EQ(large_first.pairs[0].outcome, PairOutcome::kSkippedTorqueDisturbance);
  ASSERT_EQ(large_first.estimates.size(), 1U);
  EXPECT_EQ(large_first.estimates[0].outcome, EventOutcome::kNoAcceptedPairs);
  EXPECT_FALSE(large_first.pulse_after);
}

// Pairs at one load only determine a - b u there, not b: with a commissioning error of
// -10 % a first loaded pair would put a share of it into b, and 3 b u would triple it. The
// secant stands for the incremental until pairs at a second load resolve b (less the
// commissioned gap 2 b0 u, none here: no motor.lq_rated_H).
TEST(InjectionScheduler, AnUnresolvedSaturationCurveUsesTheSecant) {
  InjectionConfig c = test_config();
  c.lq_H = 0.9 * 5.5e-3;  // commissioned 10 % low; the plant does not saturate
  c.vx_initial_V = 1.5;
  c.vx_initial_std_V = 0.01;
  c.max_load_change_A = 20.0;
  Harness h(c);
  const double iq0 = 60.0;
  answer_the_reluctance_torque(h, &iq0);
  h.run_until(5.0);
  EXPECT_NEAR(h.scheduler.lq_secant_H(60.0), 5.5e-3, 0.05e-3) << "the secant at the load seen is right";
  EXPECT_NE(h.scheduler.lq_saturation_H(), 0.0) << "b took a share of the error";
  EXPECT_EQ(h.scheduler.lq_incremental_H(60.0), h.scheduler.lq_secant_H(60.0));
  EXPECT_NEAR(mean_published_rs_error(h, 2), 0.0, 0.01);
}

// A rotor angle 0.3 deg electrical off puts psi delta = 1.7 mWb of the EMF on the measured d
// axis: at 5 A it reads as 0.34 mH of Lq (6 %), at 60 A as 0.03 mH. Taken for Lq (the learner
// without the angle's state, lq_angle_std_rad = 0), light load teaches an Lq 6 % high, and the
// curve a - b u, bent to fit 5 and 30 A, draws the incremental the loaded pairs' term needs
// (the speed loop's answer, diq = 0.15 dId) far off: +15 % at 30 A, and at 60 A, where the
// third load has brought in the curve's bend to fit the angle's 1 / iq, -46 % (+90 % before the
// bend). With the state (a prior of 0.29 deg) two loads leave c and the curve partly confounded
// (+3 % at 30 A), and the third tells them apart: c within its error bar, the incremental right
// (no bend where c is a state).
struct AngleRun {
  double rs_error_30 = 0.0;  // published estimates' mean relative error at 30 A ...
  double rs_error_60 = 0.0;  // ... and at 60 A, from the third estimate at each load
  double emf_d_Wb = 0.0;
  double emf_d_std_Wb = 0.0;
  double incremental_60_H = 0.0;
};

AngleRun angle_error_run(double lq_angle_std_rad) {
  InjectionConfig c = saturation_test_config();
  c.lq_angle_std_rad = lq_angle_std_rad;
  Harness h(c);
  h.plant.angle_error_rad = 0.3 * kPi / 180.0;
  double iq0 = 5.0;
  answer_the_reluctance_torque(h, &iq0);
  h.run_until(3.0);
  iq0 = 30.0;
  const std::size_t at_30 = h.estimates.size();
  h.run_until(6.0);
  iq0 = 60.0;
  const std::size_t at_60 = h.estimates.size();
  AngleRun r;
  r.rs_error_30 = mean_published_rs_error(h, at_30 + 2);
  h.run_until(9.0);
  r.rs_error_60 = mean_published_rs_error(h, at_60 + 2);
  r.emf_d_Wb = h.scheduler.lq_emf_d_Wb();
  r.emf_d_std_Wb = h.scheduler.lq_emf_d_std_Wb();
  r.incremental_60_H = h.scheduler.lq_incremental_H(60.0);
  return r;
}

TEST(InjectionScheduler, ARotorAngleErrorIsNotTakenForLq) {
  const double psi_delta = 0.9716 / 3.0 * 0.3 * kPi / 180.0;
  const AngleRun with = angle_error_run(0.005);
  const AngleRun without = angle_error_run(0.0);
  EXPECT_NEAR(with.emf_d_Wb, psi_delta, 3.0 * with.emf_d_std_Wb);
  EXPECT_LT(with.emf_d_std_Wb, 0.1 * psi_delta) << "three loads tell c from the curve";
  EXPECT_NEAR(with.incremental_60_H, 5.5e-3, 0.05e-3);
  EXPECT_LT(std::abs(with.rs_error_60), 0.005);
  EXPECT_LT(std::abs(with.rs_error_30), 0.05);
  EXPECT_GT(without.rs_error_30, 3.0 * std::abs(with.rs_error_30)) << "the angle taken for Lq";
  EXPECT_GT(std::abs(without.rs_error_60), 0.3);
  EXPECT_EQ(without.emf_d_Wb, 0.0);
}

// A pair whose q current idles inside the bridge's ripple band teaches the curve but not the
// angle's share c: its d-axis mean keeps what the bridge model leaves of the bridge's error, and
// c / iq has its largest lever there (docs/estimator.md section 5.6). The same pairs at 5 A with
// the band above their current leave c at its prior, mean and variance, and learn Lq; with the
// band below it, they move c toward the plant's angle error.
TEST(InjectionScheduler, APairIdlingInsideTheBridgesBandDoesNotTeachTheAngle) {
  const double psi = saturation_test_config().flux_linkage_Wb;
  const double prior_std_rad = 0.005;
  struct Learned {
    double emf_d_Wb;
    double emf_d_std_Wb;
    double lq_std_H;
  };
  auto run = [&](double band_A) {
    InjectionConfig c = saturation_test_config();
    c.lq_angle_std_rad = prior_std_rad;
    Harness h(c);
    h.plant.angle_error_rad = 0.3 * kPi / 180.0;
    h.scheduler.set_bridge_band(band_A);
    const double iq0 = 5.0;
    answer_the_reluctance_torque(h, &iq0);
    h.run_until(3.0);
    return Learned{h.scheduler.lq_emf_d_Wb(), h.scheduler.lq_emf_d_std_Wb(), h.scheduler.lq_std_H()};
  };
  const Learned inside = run(6.0);
  const Learned outside = run(4.0);
  const double prior_lq_std_H = saturation_test_config().lq_initial_std_fraction * saturation_test_config().lq_H;
  EXPECT_EQ(inside.emf_d_Wb, 0.0) << "c left at its prior's mean";
  EXPECT_DOUBLE_EQ(inside.emf_d_std_Wb, psi * prior_std_rad) << "and its prior's width";
  // (Lq's error bar at 5 A cannot fall below what c leaves open there, psi sigma / iq = 0.32 mH.)
  EXPECT_LT(inside.lq_std_H, 0.75 * prior_lq_std_H) << "the curve learned";
  EXPECT_GT(outside.emf_d_Wb, 0.1 * psi * 0.3 * kPi / 180.0) << "outside the band the pairs teach c";
  EXPECT_LT(outside.emf_d_std_Wb, 0.9 * psi * prior_std_rad);
}

// The drive gives the Lq learner the rotor-angle check's result as c's prior (what a pair at one
// load cannot tell from Lq): with the true angle as its prior, a machine seen at one light load
// learns its Lq, 10 % off as commissioned, as well as with an exact encoder; without it (the
// default prior, 0) the angle is taken for Lq. On a machine configured as salient the prior is
// not used.
TEST(InjectionScheduler, TheAngleChecksResultIsTheAnglesPrior) {
  const double delta = 0.3 * kPi / 180.0;
  auto learned_lq = [&](bool prior, double max_torque_disturbance_Nm) {
    InjectionConfig c = saturation_test_config();
    c.lq_H = 0.9 * 5.5e-3;
    c.max_torque_disturbance_Nm = max_torque_disturbance_Nm;
    Harness h(c);
    h.plant.angle_error_rad = delta;
    if (prior) {
      h.scheduler.set_angle_prior(delta, 0.02 * kPi / 180.0);
    }
    const double iq0 = 10.0;
    answer_the_reluctance_torque(h, &iq0);
    h.run_until(4.0);
    return h.scheduler.lq_secant_H(10.0);
  };
  const double angle_share_H = 0.9716 / 3.0 * delta / 10.0;  // psi delta / iq: 0.17 mH
  EXPECT_NEAR(learned_lq(true, 0.0), 5.5e-3, 0.2 * angle_share_H);
  EXPECT_NEAR(learned_lq(false, 0.0), 5.5e-3 - angle_share_H, 0.2 * angle_share_H) << "the angle taken for Lq";
  EXPECT_NEAR(learned_lq(true, 5.0), 5.5e-3 - angle_share_H, 0.2 * angle_share_H) << "salient: no angle state";
}

// A drive that cruises at one load never resolves b: its pairs measure the secant there and
// nothing of the gap 2 b u to the incremental, which the speed loop's answer to the reluctance
// torque needs (diq = 0.15 dId). The commissioned secant at the rated current (a flux map's
// figure, lq_rated_H) gives that gap; without it the loaded estimates read high by about
// w diq 2 b u / (Rs dId).
double one_load_rs_error(double lq_rated_H) {
  InjectionConfig c = saturation_test_config();
  c.rated_current_A = 45.1;
  c.lq_rated_H = lq_rated_H;
  Harness h(c);
  h.plant.lq_sat_H = 0.55e-3;  // secant 10 % lower at the current limit (80 A)
  const double iq0 = 60.0;
  answer_the_reluctance_torque(h, &iq0);
  h.run_until(5.0);
  const double gap = h.scheduler.lq_secant_H(60.0) - h.scheduler.lq_incremental_H(60.0);
  // The plant's gap at 60 A: 2 b u = 2 x 0.55 mH x (60 / 80)^2.
  const double plant_gap = 2.0 * h.plant.lq_sat_H * (60.0 / 80.0) * (60.0 / 80.0);
  if (lq_rated_H > 0.0) {
    EXPECT_NEAR(gap, plant_gap, 0.02 * plant_gap) << "the commissioned gap";
  } else {
    EXPECT_EQ(gap, 0.0) << "unresolved and not commissioned: the secant";
  }
  return mean_published_rs_error(h, 2);
}

// The commissioned curve itself: b0 = (lq_H - lq_rated_H) / (rated / limit)^2 is b's starting
// value; with learning off the curve keeps it, so the secant is lq_H - b0 u and the incremental
// lq_H - 3 b0 u at every load.
TEST(InjectionScheduler, TheCommissionedCurveIsTheRatedSecantsExtrapolation) {
  InjectionConfig c = test_config();  // current limit 80 A
  c.lq_H = 5.5e-3;
  c.rated_current_A = 40.0;
  c.lq_rated_H = 5.4e-3;
  c.learn_lq = false;
  const InjectionScheduler s(c, kPeriod, 64);
  const double b0 = 0.1e-3 / (0.5 * 0.5);
  EXPECT_NEAR(s.lq_saturation_H(), b0, 1e-12);
  EXPECT_NEAR(s.lq_secant_H(40.0), 5.4e-3, 1e-12) << "the map's point";
  const double u = (60.0 / 80.0) * (60.0 / 80.0);
  EXPECT_NEAR(s.lq_secant_H(60.0), 5.5e-3 - b0 * u, 1e-12);
  EXPECT_NEAR(s.lq_incremental_H(60.0), 5.5e-3 - 3.0 * b0 * u, 1e-12);
  c.lq_rated_H = 0.0;
  const InjectionScheduler none(c, kPeriod, 64);
  EXPECT_EQ(none.lq_saturation_H(), 0.0);
  EXPECT_EQ(none.lq_incremental_H(60.0), 5.5e-3);
}

// The 30 mohm IPM's q axis (the plant's saturating curve): psi = Ls i + (L - Ls) k x / sqrt(1 + x^2),
// x = i / k, and its flux map's secant at a quarter to twice the rated 141 A.
struct SaturatingAxis {
  double l_H = 0.45e-3;
  double l_sat_H = 0.30e-3;
  double knee_A = 220.0;
  [[nodiscard]] double secant(double i) const {
    return l_sat_H + (l_H - l_sat_H) / std::sqrt(1.0 + (i / knee_A) * (i / knee_A));
  }
  [[nodiscard]] double incremental(double i) const {
    const double r = std::sqrt(1.0 + (i / knee_A) * (i / knee_A));
    return l_sat_H + (l_H - l_sat_H) / (r * r * r);
  }
};

InjectionConfig mapped_config(const SaturatingAxis& axis, const std::vector<double>& currents_A) {
  InjectionConfig c = test_config();
  c.lq_H = axis.l_H;
  c.current_limit_A = 300.0;
  c.rated_current_A = 141.0;
  c.learn_lq = false;
  for (std::size_t k = 0; k < currents_A.size(); ++k) {
    c.lq_map.current_A[k] = currents_A[k];
    c.lq_map.secant_H[k] = axis.secant(currents_A[k]);
  }
  c.lq_map.points = static_cast<int>(currents_A.size());
  return c;
}

// The gap between the secant Lq that pairs at one load measure and the incremental their fit
// needs is the map's slope: iq d(secant)/diq. Through six points of a saturating curve the
// shape gives it within 3 % from 20 to 200 A (2.1 % at worst, next to the rated point), and
// within 20 % in the last and widest segment, 212-282 A, whose end has only a one-sided slope
// (16 % at 280 A); the secant within 0.2 % everywhere (0.11 % at worst, in that segment), and
// through the points themselves. The quadratic through the rated point alone misses the gap
// by 10 % at 75 A, where the IPM cruises (docs/estimator.md §5.1).
TEST(LqShape, AFluxMapOfSeveralPointsGivesTheIncrementalBetweenItsPoints) {
  const SaturatingAxis axis;
  const InjectionConfig c = mapped_config(axis, {35.0, 70.0, 106.0, 141.0, 212.0, 282.0});
  const InjectionScheduler s(c, kPeriod, 64);
  for (const double i : {35.0, 70.0, 106.0, 141.0, 212.0, 282.0}) {
    EXPECT_NEAR(s.lq_secant_H(i), axis.secant(i), 1e-12) << "the map's point at " << i << " A";
  }
  for (double i = 20.0; i <= 280.0; i += 5.0) {
    const double gap = axis.secant(i) - axis.incremental(i);
    EXPECT_NEAR(s.lq_secant_H(i) - s.lq_incremental_H(i), gap, (i <= 200.0 ? 0.03 : 0.2) * gap) << i << " A";
    EXPECT_NEAR(s.lq_secant_H(i), axis.secant(i), 2e-3 * axis.secant(i)) << i << " A";
  }
  InjectionConfig point = mapped_config(axis, {});
  point.lq_rated_H = axis.secant(141.0);
  const InjectionScheduler quadratic(point, kPeriod, 64);
  const double gap_75 = axis.secant(75.0) - axis.incremental(75.0);
  EXPECT_LT(quadratic.lq_secant_H(75.0) - quadratic.lq_incremental_H(75.0), 0.92 * gap_75);
}

// One point is the quadratic through it, to the last bit (the map of lq_rated_H and a map of
// that one point are the same curve), and no saturation at the map's end is one Lq.
TEST(LqShape, OnePointIsTheQuadraticAndAFlatMapIsOneLq) {
  const SaturatingAxis axis;
  InjectionConfig c = mapped_config(axis, {141.0});
  const LqShape one(c);
  c.lq_map.points = 0;
  c.lq_rated_H = axis.secant(141.0);
  const LqShape rated(c);
  EXPECT_EQ(one.b0_H(), rated.b0_H());
  EXPECT_GT(one.b0_H(), 0.0);
  for (const double i : {0.0, 50.0, 141.0, 250.0, 400.0}) {
    const double u = std::min((i / 300.0) * (i / 300.0), 1.44);
    EXPECT_EQ(one.at(i).s, u);
    EXPECT_EQ(one.at(i).h, 3.0 * u);
    EXPECT_EQ(rated.at(-i).s, u) << "the sign of iq does not matter";
  }
  InjectionConfig flat = mapped_config(axis, {70.0, 141.0});
  flat.lq_map.secant_H = {axis.l_H, axis.l_H};
  EXPECT_EQ(LqShape(flat).b0_H(), 0.0);
}

// A map sampled from the quadratic curve itself (secant a - b0 u) is that curve: the three-point
// slopes of a straight line in u are its slope, and the Hermite curve between them the line.
// A map built in code that is no map (not ascending, NaN, above lq_H) is one Lq, never NaN.
TEST(LqShape, AMapOfTheQuadraticIsTheQuadraticAndANonMapIsOneLq) {
  InjectionConfig c = test_config();  // current limit 80 A
  c.lq_H = 5.5e-3;
  const double b0 = 0.6e-3;
  const std::array<double, 4> currents{20.0, 40.0, 60.0, 80.0};
  for (std::size_t k = 0; k < currents.size(); ++k) {
    c.lq_map.current_A[k] = currents[k];
    c.lq_map.secant_H[k] = c.lq_H - b0 * (currents[k] / 80.0) * (currents[k] / 80.0);
  }
  c.lq_map.points = 4;
  const LqShape shape(c);
  EXPECT_NEAR(shape.b0_H(), b0, 1e-15);
  for (double i = 0.0; i <= 100.0; i += 2.5) {
    const double u = std::min((i / 80.0) * (i / 80.0), 1.44);  // (the curve's cap, 1.2 x the limit)
    EXPECT_NEAR(shape.at(i).s, u, 1e-12) << i << " A";
    EXPECT_NEAR(shape.at(i).h, 3.0 * u, 1e-12) << i << " A";
  }
  for (const double bad : {std::nan(""), 10.0, 6e-3}) {
    InjectionConfig broken = c;
    if (bad == 10.0) {
      broken.lq_map.current_A[2] = bad;  // not ascending
    } else {
      broken.lq_map.secant_H[1] = bad;   // NaN, or above lq_H
    }
    const LqShape none(broken);
    EXPECT_EQ(none.b0_H(), 0.0) << bad;
    EXPECT_EQ(none.at(50.0).s, (50.0 / 80.0) * (50.0 / 80.0)) << "the quadratic's shape, with no saturation";
  }
}

// A map with a sharp knee (flat to 100 A, then falling fast): the curve between its points
// neither rises nor overshoots (the secant only falls with load), and the incremental stays
// below the secant.
TEST(LqShape, ASharpKneeGivesAMonotoneCurve) {
  InjectionConfig c = test_config();
  c.lq_H = 1.0e-3;
  c.current_limit_A = 200.0;
  const std::array<double, 5> currents{50.0, 100.0, 120.0, 150.0, 200.0};
  const std::array<double, 5> secants{1.0e-3, 0.999e-3, 0.90e-3, 0.80e-3, 0.78e-3};
  for (std::size_t k = 0; k < currents.size(); ++k) {
    c.lq_map.current_A[k] = currents[k];
    c.lq_map.secant_H[k] = secants[k];
  }
  c.lq_map.points = static_cast<int>(currents.size());
  const LqShape shape(c);
  double last = -1.0;
  for (double i = 0.0; i <= 240.0; i += 0.5) {
    const LqShape::At a = shape.at(i);
    EXPECT_GE(a.s, last) << i << " A";
    EXPECT_GE(a.h, a.s - 1e-12) << i << " A";
    last = a.s;
  }
  EXPECT_NEAR(c.lq_H - shape.b0_H() * shape.at(100.0).s, 0.999e-3, 1e-12);
}

TEST(InjectionScheduler, ACommissionedSaturationGivesTheIncrementalAtOneLoad) {
  // The plant's secant at the rated 45.1 A: 5.5 mH - 0.55 mH x (45.1 / 80)^2.
  const double rated_secant_H = 5.5e-3 - 0.55e-3 * (45.1 / 80.0) * (45.1 / 80.0);
  const double commissioned = one_load_rs_error(rated_secant_H);
  EXPECT_LT(std::abs(commissioned), 0.01) << "one load, saturation commissioned";
  const double unknown = one_load_rs_error(0.0);
  EXPECT_GT(unknown, 0.03) << "one load, saturation unknown: the loaded Rs reads high";
}

TEST(InjectionScheduler, SkipsEveryLevelWhenTheBudgetIsTooSmallAndRetries) {
  InjectionConfig c = test_config();
  Harness h(c);
  h.motoring_A = {0.0, 79.9};  // no current left for injection
  h.run_until(0.0105);
  ASSERT_GE(h.pairs.size(), 2U);
  for (std::size_t k = 0; k < 2; ++k) {
    EXPECT_EQ(h.pairs[k].outcome, PairOutcome::kRejectedCurrentLimit);
    EXPECT_EQ(h.pairs[k].level_index, static_cast<int>(k));
    EXPECT_LT(h.pairs[k].f_A, c.f_min_A);
  }
  ASSERT_EQ(h.estimates.size(), 1U);
  EXPECT_EQ(h.estimates[0].outcome, EventOutcome::kNoAcceptedPairs);
  // No injection at all, and the next attempt after retry_s rather than interval_s.
  for (const StepRecord& r : h.records) EXPECT_EQ(r.out.injection_A.d, 0.0);
  EXPECT_NEAR(h.scheduler.next_event_s(), c.first_event_s + kPeriod + c.retry_s, 2.5 * kPeriod);
}

TEST(InjectionScheduler, DisabledDriveAbortsThePair) {
  InjectionConfig c = test_config();
  Harness h(c);
  double abort_time = -1.0;
  h.hook = [&](Harness& x) {
    if (abort_time < 0.0 && !x.records.empty() && x.records.back().out.phase == P::kRecord1) {
      x.enabled = false;
      abort_time = x.time_s;
    }
  };
  h.run_until(0.45);
  ASSERT_EQ(h.pairs.size(), 1U);
  EXPECT_EQ(h.pairs[0].outcome, PairOutcome::kAborted);
  EXPECT_EQ(h.pairs[0].level_index, 0);
  // The event reports that it was aborted, and publishes nothing.
  ASSERT_EQ(h.estimates.size(), 1U);
  EXPECT_EQ(h.estimates[0].outcome, EventOutcome::kAborted);
  for (const StepRecord& r : h.records) {
    if (r.time_s >= abort_time) {
      EXPECT_FALSE(r.out.active);
      EXPECT_EQ(r.out.injection_A.d, 0.0);
      EXPECT_EQ(r.out.phase, P::kIdle);
    }
  }
  EXPECT_GE(h.scheduler.next_event_s(), abort_time + c.retry_s - 1e-9);
}

// The drive ends a pair whose held field weakening no longer suits the speed
// (SchedulerInput::release_motoring, DriveController::weaken_field): at once, counted as
// aborted, the event with it, and no pulse from that period on.
TEST(InjectionScheduler, ReleasingTheMotoringPointAbortsThePair) {
  InjectionConfig c = test_config();
  Harness h(c);
  double release_time = -1.0;
  h.hook = [&](Harness& x) {
    if (release_time < 0.0 && !x.records.empty() && x.records.back().out.phase == P::kRecord1) {
      x.release_motoring = true;
      release_time = x.time_s;
    } else {
      x.release_motoring = false;  // (one period of it suffices)
    }
  };
  h.run_until(0.45);
  ASSERT_GE(h.pairs.size(), 1U);
  EXPECT_EQ(h.pairs[0].outcome, PairOutcome::kAborted);
  EXPECT_EQ(h.pairs[0].abort_cause, AbortCause::kMotoringNeedsVoltage);
  ASSERT_GE(h.estimates.size(), 1U);
  EXPECT_EQ(h.estimates[0].outcome, EventOutcome::kAborted);
  for (const StepRecord& r : h.records) {
    if (r.time_s >= release_time && r.time_s < release_time + c.retry_s - 1e-9) {
      EXPECT_FALSE(r.out.active);
      EXPECT_EQ(r.out.injection_A.d, 0.0);
    }
  }
  EXPECT_GE(h.scheduler.next_event_s(), release_time + c.retry_s - 1e-9);
  // Between pairs it ends nothing: the flag up in every idle period, the event publishes.
  Harness idle(c);
  idle.hook = [](Harness& x) { x.release_motoring = x.records.empty() || x.records.back().out.phase == P::kIdle; };
  idle.run_until(0.45);
  ASSERT_GE(idle.estimates.size(), 1U);
  EXPECT_EQ(idle.estimates[0].outcome, EventOutcome::kPublished);
  for (const PairResult& p : idle.pairs) EXPECT_NE(p.outcome, PairOutcome::kAborted);
}

// The motoring current that grows during a pair (the speed loop's answer to a step) never takes
// the sum with the pulse past the current limit: crowded a little (here |i| would reach 80.6 A
// of 80), the pulse is cut to fit and the pair goes on; crowded more, the pair ends at once.
TEST(InjectionScheduler, APulseIsCutOrEndedToKeepTheCurrentLimit) {
  const InjectionConfig c = test_config();  // F = 25 A, 80 A limit
  auto run = [&](double iq_during_A) {
    Harness h(c);
    h.motoring_A = {0.0, 40.0};
    std::vector<double> motoring_iq;  // each step's, as the hook leaves it
    h.hook = [&](Harness& x) {
      if (!x.records.empty() && x.records.back().out.phase == P::kRecord1) x.motoring_A.q = iq_during_A;
      motoring_iq.push_back(x.motoring_A.q);
    };
    h.run_until(0.45);
    double worst_A = 0.0;
    for (std::size_t k = 0; k < h.records.size(); ++k) {
      const Dq& inj = h.records[k].out.injection_A;
      worst_A = std::max(worst_A, std::hypot(inj.d, motoring_iq[k] + inj.q));
    }
    EXPECT_LE(worst_A, c.current_limit_A + 1e-9) << "motoring iq " << iq_during_A << " A";
    return h.pairs.empty() ? std::pair{PairOutcome::kCount, AbortCause::kCount}
                           : std::pair{h.pairs[0].outcome, h.pairs[0].abort_cause};
  };
  // sqrt(80^2 - 76^2) = 25.0 A of room: the full pulse fits; at 76.2 A it is cut by 5 %.
  EXPECT_NE(run(76.2).first, PairOutcome::kAborted);
  // At 79 A only 12.6 A of room: half the pulse, the pair ends.
  EXPECT_EQ(run(79.0), std::pair(PairOutcome::kAborted, AbortCause::kCurrentLimit));
}

TEST(InjectionScheduler, LosingSpeedAbortsAnAngleBasedPair) {
  InjectionConfig c = test_config();
  Harness h(c);
  h.hook = [&](Harness& x) {
    if (!x.records.empty() && x.records.back().out.phase == P::kWaitArc) x.omega_e_rad_s = 10.0;
  };
  h.run_until(0.2);
  ASSERT_FALSE(h.pairs.empty());
  EXPECT_EQ(h.pairs[0].outcome, PairOutcome::kAborted);
  EXPECT_EQ(h.pairs[0].abort_cause, AbortCause::kSpeedLost);
  for (const EventEstimate& e : h.estimates) EXPECT_NE(e.outcome, EventOutcome::kPublished);
}

// A shaft that stopped under an angle-based pair (a press between its strokes) is measured at
// rest: the event starts again once the shaft has rested a time-based recording's length with
// its current holding, not after retry_s (a 0.7 s dwell had every retry fall in the next
// stroke). Not while the current still moves, nor on a shaft the winding's derating stalled.
TEST(InjectionScheduler, AShaftThatStoppedIsMeasuredOnceItRests) {
  InjectionConfig c = test_config();
  c.interval_s = 10.0;  // only the retry can start the next event in this test
  struct Run {
    double abort_s = -1.0;
    double next_start_s = -1.0;
    bool next_time_based = false;
    bool published = false;
  };
  // `iq_ramp_A_per_s`: the motoring iq keeps moving that fast after the stop, for 0.3 s;
  // `motoring_limit_A`: the winding's derating leaves the motoring that much; `disable_s`: the
  // drive is disabled that long right after the stop.
  const auto run = [&](double motoring_limit_A, double iq_ramp_A_per_s, double disable_s = 0.0) {
    Harness h(c);
    h.motoring_A = {0.0, 10.0};
    h.scheduler.set_motoring_current_limit(motoring_limit_A);
    Run r;
    h.hook = [&](Harness& x) {
      if (r.abort_s < 0.0 && !x.records.empty() && x.records.back().out.phase == P::kWaitArc) {
        x.omega_e_rad_s = 0.0;  // the shaft stops under the pair
      }
      if (r.abort_s >= 0.0 && x.time_s - r.abort_s < 0.3) {
        x.motoring_A.q += iq_ramp_A_per_s * kPeriod;
      }
      x.enabled = !(r.abort_s >= 0.0 && x.time_s - r.abort_s < disable_s);
    };
    while (h.time_s < 0.9) {
      const std::size_t pairs_before = h.pairs.size();
      h.step();
      if (r.abort_s < 0.0 && h.pairs.size() > pairs_before && h.pairs.back().outcome == PairOutcome::kAborted) {
        EXPECT_EQ(h.pairs.back().abort_cause, AbortCause::kSpeedLost);
        r.abort_s = h.time_s;
      } else if (r.abort_s >= 0.0 && r.next_start_s < 0.0 && h.records.back().out.phase != P::kIdle) {
        r.next_start_s = h.time_s;
      }
      if (r.abort_s >= 0.0 && h.pairs.size() > pairs_before && h.pairs.back().outcome == PairOutcome::kAccepted) {
        r.next_time_based = h.pairs.back().time_based;
      }
    }
    for (const EventEstimate& e : h.estimates) r.published = r.published || e.outcome == EventOutcome::kPublished;
    return r;
  };
  constexpr double kNoLimit = std::numeric_limits<double>::infinity();
  const Run rests = run(kNoLimit, 0.0);
  ASSERT_GE(rests.abort_s, 0.0);
  ASSERT_GE(rests.next_start_s, 0.0) << "no event at rest before retry_s";
  EXPECT_GE(rests.next_start_s - rests.abort_s, c.record_time_s);
  EXPECT_LT(rests.next_start_s - rests.abort_s, c.record_time_s + 0.01);
  EXPECT_TRUE(rests.next_time_based);
  EXPECT_TRUE(rests.published);
  // The current moving 20 A/s (0.4 A a recording, the guard's 1.5 A in 75 ms): the rest counts
  // from when it holds.
  const Run settling = run(kNoLimit, 20.0);
  ASSERT_GE(settling.next_start_s, 0.0);
  EXPECT_GE(settling.next_start_s - settling.abort_s, 0.3 + c.record_time_s - 0.04);
  // A derating that leaves the 10 A at rest room (20 A): as without one. One that leaves 10.5 A
  // (a shaft it may have stalled): the retry delay, as before.
  EXPECT_GE(run(20.0, 0.0).next_start_s, 0.0);
  const Run stalled = run(10.5, 0.0);
  ASSERT_GE(stalled.abort_s, 0.0);
  EXPECT_LT(stalled.next_start_s, 0.0) << "an event started within retry_s on a shaft the derating may hold";
  // Disabled for 0.1 s after the stop: the rest before is no rest, and the retry delay holds.
  const Run disabled = run(kNoLimit, 0.0, 0.1);
  ASSERT_GE(disabled.abort_s, 0.0);
  EXPECT_LT(disabled.next_start_s, 0.0) << "an event started within retry_s after a disable";
}

// A press at 60 strokes a minute, each stroke holding the current at its limit for 0.2 s: an
// event that starts in a stroke finds no budget, and a retry exactly retry_s (1 s) later finds
// the next stroke at the same phase, for ever; so does an event aborted by a stroke's start and
// followed at an interval of whole seconds. Jittered from the second refusal in a row (the
// default), an event lands outside the strokes within a few tries.
TEST(InjectionScheduler, RepeatedRefusalsAreNotLockedToADutyWhosePeriodDividesTheDelay) {
  InjectionConfig c = test_config();
  c.interval_s = 2.0;  // after an event aborted by the next stroke: 2 s from its start, jittered
  ASSERT_DOUBLE_EQ(c.retry_s, 1.0);
  ASSERT_GT(c.retry_jitter, 0.0) << "the default delays after repeated refusals are jittered";
  const auto run = [](const InjectionConfig& cfg) {
    Harness h(cfg);
    h.hook = [](Harness& x) {
      const double phase = x.time_s - std::floor(x.time_s);
      x.motoring_A = {0.0, phase < 0.2 ? 79.9 : 10.0};  // the stroke at its 80 A limit
    };
    h.run_until(12.0);
    return h;
  };
  const auto published = [](const Harness& h) {
    int n = 0;
    for (const EventEstimate& e : h.estimates) n += e.outcome == EventOutcome::kPublished ? 1 : 0;
    return n;
  };
  InjectionConfig exact = c;
  exact.retry_jitter = 0.0;
  const Harness locked = run(exact);
  EXPECT_GE(locked.pairs.size(), 22U) << "a refused attempt every second";
  for (const PairResult& p : locked.pairs) EXPECT_EQ(p.outcome, PairOutcome::kRejectedCurrentLimit);
  EXPECT_EQ(published(locked), 0);
  const Harness jittered = run(c);
  ASSERT_FALSE(jittered.pairs.empty());
  EXPECT_EQ(jittered.pairs[0].outcome, PairOutcome::kRejectedCurrentLimit) << "the first event (0.01 s) lies in a stroke";
  EXPECT_GE(published(jittered), 2) << "the retries stayed in the strokes";
  ASSERT_GE(jittered.pairs.size(), 3U);
  EXPECT_NEAR(jittered.pairs[2].time_s - jittered.pairs[1].time_s, c.retry_s, 1.5 * kPeriod)
      << "the first retry after a refusal is exact";
  // A retry after an event refused for its budget (both levels refused, the next pair the next
  // event's first): retry_s (1 + retry_jitter v), v in [0, 1), later; exactly retry_s the first time.
  int retries = 0;
  for (std::size_t i = 0; i + 2 < jittered.pairs.size(); ++i) {
    const PairResult& a = jittered.pairs[i];
    const PairResult& b = jittered.pairs[i + 1];
    const PairResult& next = jittered.pairs[i + 2];
    if (a.outcome == PairOutcome::kRejectedCurrentLimit && a.level_index == 0 &&
        b.outcome == PairOutcome::kRejectedCurrentLimit && b.level_index == 1 && next.level_index == 0) {
      ++retries;
      EXPECT_GE(next.time_s - b.time_s, c.retry_s - kPeriod);
      EXPECT_LE(next.time_s - b.time_s, c.retry_s * (1.0 + c.retry_jitter) + kPeriod);
    }
  }
  EXPECT_GE(retries, 1);
}

// The jitter starts at the second refusal in a row and ends with an event that yields pairs:
// refused events at the current limit (the first retry exact, the next ones retry_s to
// retry_s (1 + retry_jitter) later, not all alike), then an event that publishes, then refused
// events again, whose first retry is exact again.
TEST(InjectionScheduler, TheJitterStartsAtTheSecondRefusalAndEndsWithAnEventThatYieldsPairs) {
  InjectionConfig c = test_config();
  c.interval_s = 10.0;  // only retries in this test, but for the event that publishes
  Harness h(c);
  const auto refusal_times = [&](std::size_t count) {
    std::vector<double> t;
    while (t.size() < count && h.time_s < 60.0) {
      const std::size_t before = h.pairs.size();
      h.step();
      if (h.pairs.size() > before && h.pairs.back().level_index == 1) {
        EXPECT_EQ(h.pairs.back().outcome, PairOutcome::kRejectedCurrentLimit);
        t.push_back(h.time_s);  // the event's end: both levels refused
      }
    }
    return t;
  };
  h.motoring_A = {0.0, 79.9};
  const std::vector<double> first = refusal_times(6);
  ASSERT_EQ(first.size(), 6U);
  // (From one event's end to the next's: the retry, and the two periods its levels take.)
  EXPECT_NEAR(first[1] - first[0], c.retry_s + 2 * kPeriod, 0.5 * kPeriod) << "the first retry is exact";
  double shortest = 1e9;
  double longest = 0.0;
  for (std::size_t k = 2; k < first.size(); ++k) {
    const double d = first[k] - first[k - 1];
    EXPECT_GE(d, c.retry_s - kPeriod);
    EXPECT_LE(d, c.retry_s * (1.0 + c.retry_jitter) + 3 * kPeriod);
    shortest = std::min(shortest, d);
    longest = std::max(longest, d);
  }
  EXPECT_GT(longest - shortest, 0.1 * c.retry_s) << "the repeated retries are not jittered";
  // Room for the pulses: the next event publishes.
  h.motoring_A = {0.0, 10.0};
  const std::size_t estimates_before = h.estimates.size();
  while (h.time_s < first.back() + 3.0 && (h.estimates.size() == estimates_before ||
                                           h.estimates.back().outcome != EventOutcome::kPublished)) {
    h.step();
  }
  ASSERT_EQ(h.estimates.back().outcome, EventOutcome::kPublished);
  // Refused again (from the next event, the interval later): the first retry is exact again.
  h.motoring_A = {0.0, 79.9};
  const std::vector<double> again = refusal_times(2);
  ASSERT_EQ(again.size(), 2U);
  EXPECT_NEAR(again[1] - again[0], c.retry_s + 2 * kPeriod, 0.5 * kPeriod) << "an event that yielded pairs ended the jitter";
}

// After recording 1 of every pair, `change` alters the operating point for the rest of it.
void run_with_change_after_record1(Harness& h, const std::function<void(Harness&)>& change,
                                   const std::function<void(Harness&)>& restore, double until) {
  h.hook = [&](Harness& x) {
    if (x.records.empty()) return;
    const P last = x.records.back().out.phase;
    if (last == P::kRampDown || last == P::kWaitArc || last == P::kRecord2) {
      // Between the recordings or in recording 2 of the pair (not the final ramp-down: the
      // recorder ignores it).
      change(x);
    } else {
      restore(x);
    }
  };
  h.run_until(until);
}

TEST(InjectionScheduler, SpeedChangeBetweenRecordingsRejectsThePair) {
  Harness h(test_config());
  run_with_change_after_record1(
      h, [](Harness& x) { x.omega_e_rad_s = 310.0; }, [](Harness& x) { x.omega_e_rad_s = 300.0; }, 0.45);
  ASSERT_EQ(h.pairs.size(), 2U);
  for (const PairResult& p : h.pairs) {
    EXPECT_EQ(p.outcome, PairOutcome::kRejectedSpeedChange) << to_string(p.outcome);
    EXPECT_NEAR(p.delta_omega_e_rad_s, -10.0, 1e-9);
  }
  ASSERT_EQ(h.estimates.size(), 1U);
  EXPECT_EQ(h.estimates[0].outcome, EventOutcome::kNoAcceptedPairs);
  // A change within the limit (max(3, 2 % of 300) = 6 rad/s) is accepted.
  Harness ok(test_config());
  run_with_change_after_record1(
      ok, [](Harness& x) { x.omega_e_rad_s = 305.0; }, [](Harness& x) { x.omega_e_rad_s = 300.0; }, 0.45);
  ASSERT_EQ(ok.pairs.size(), 2U);
  EXPECT_EQ(ok.pairs[0].outcome, PairOutcome::kAccepted) << to_string(ok.pairs[0].outcome);
}

TEST(InjectionScheduler, LoadChangeBetweenRecordingsRejectsThePair) {
  Harness h(test_config());
  run_with_change_after_record1(
      h, [](Harness& x) { x.motoring_A = {0.0, 3.0}; }, [](Harness& x) { x.motoring_A = {0.0, 0.0}; }, 0.45);
  ASSERT_EQ(h.pairs.size(), 2U);
  for (const PairResult& p : h.pairs) {
    EXPECT_EQ(p.outcome, PairOutcome::kRejectedLoadChange) << to_string(p.outcome);
    EXPECT_NEAR(p.delta_iq_A, -3.0, 0.05);
  }
  ASSERT_EQ(h.estimates.size(), 1U);
  EXPECT_EQ(h.estimates[0].outcome, EventOutcome::kNoAcceptedPairs);
}

// A salient machine (Ld 1 mH below Lq) whose torque is held through every pulse (by the
// scheduler's torque-neutral pulses, or by the speed loop): iq (psi + (Ld - Lq) id) = iq0 psi,
// so iq moves by 6.2 A between the +25 A and -25 A recordings at 40 A of load, four times the
// 1.5 A guard. That move is the injection's own, and the fit models its d-axis voltage
// (Lq d(w iq)): on a machine configured as salient (a torque budget) the pairs are accepted and
// read Rs right, whether the move is full, half or none. The same move the other way, or twice the full answer, is no answer
// to the pulses (the load changed), and without the budget (a machine configured as round-rotor) or with Ld = Lq every
// such move is judged as a load change: rejected.
int load_changes_rejected(double ld_H, double answer, bool configured_salient, double* rs_error) {
  InjectionConfig c = test_config();
  c.ld_H = ld_H;
  c.learn_lq = false;     // the commissioned Lq is the plant's
  c.vx_initial_V = 1.5;   // and the bridge's voltage known (a calibrated drive; at this load
  c.vx_initial_std_V = 0.01;  // the events do not learn it)
  c.max_torque_disturbance_Nm = configured_salient ? 10.0 : 0.0;  // 6 Nm at 40 A and 25 A
  Harness h(c);
  h.plant.ld_H = ld_H;
  const double iq0 = 40.0;
  // The q-current's move: the answer of a machine with Ld - Lq = -1 mH, times `answer`. On a
  // machine configured as salient the scheduler makes that move itself (its torque-neutral
  // pulses, with the model's Ld - Lq), and the speed loop's share is what is left: the motoring
  // reference here is the total over the compensation's factor flux1 / flux0.
  const double model_saliency_H = configured_salient ? ld_H - c.lq_H : 0.0;
  h.hook = [=](Harness& x) {
    const double id = x.records.empty() ? 0.0 : x.records.back().out.injection_A.d;
    const double held = iq0 * c.flux_linkage_Wb / (c.flux_linkage_Wb - 1.0e-3 * id);
    const double total = iq0 + answer * (held - iq0);
    x.motoring_A = {0.0, total * (c.flux_linkage_Wb + model_saliency_H * id) / c.flux_linkage_Wb};
  };
  h.run_until(3.0);
  int rejected = 0;
  for (const PairResult& p : h.pairs) {
    rejected += p.outcome == PairOutcome::kRejectedLoadChange ? 1 : 0;
    if (p.f_A > 20.0 && p.outcome != PairOutcome::kAborted) {
      EXPECT_NEAR(std::abs(p.delta_iq_A), 6.2 * std::abs(answer), 0.3) << "the move at F = 25 A";
    }
  }
  EXPECT_GE(h.pairs.size(), 8U);
  *rs_error = rejected == 0 ? mean_published_rs_error(h, 0) : 1.0;
  return rejected;
}

// On a machine configured as salient (a torque budget) every fixed-magnitude pulse carries the
// q-current that holds the torque 3/2 p iq (psi + (Ld - Lq) id) of the motoring point, with the
// model's Ld - Lq (commissioned Ld, learned secant Lq); on a round rotor's configuration (no
// budget) the pulse is on the d-axis alone.
TEST(InjectionScheduler, ASalientMachinesPulsesHoldTheTorque) {
  for (const bool configured_salient : {true, false}) {
    InjectionConfig c = test_config();
    c.ld_H = 4.5e-3;  // 1 mH below Lq
    c.learn_lq = false;
    c.max_torque_disturbance_Nm = configured_salient ? 10.0 : 0.0;
    Harness h(c);
    h.plant.ld_H = c.ld_H;
    h.motoring_A = {0.0, 40.0};
    h.run_until(0.45);
    const double psi = c.flux_linkage_Wb;
    const double saliency = c.ld_H - c.lq_H;
    int pulses = 0;
    for (const StepRecord& r : h.records) {
      const Dq& inj = r.out.injection_A;
      if (inj.d == 0.0) {
        EXPECT_EQ(inj.q, 0.0);
        continue;
      }
      ++pulses;
      if (!configured_salient) {
        EXPECT_EQ(inj.q, 0.0);
        continue;
      }
      const double torque_flux = (psi + saliency * inj.d) * (40.0 + inj.q);
      EXPECT_NEAR(torque_flux, psi * 40.0, 1e-9 * psi * 40.0) << "id " << inj.d;
      EXPECT_EQ(inj.q > 0.0, inj.d > 0.0) << "Ld < Lq: a positive id lowers the torque, so iq rises";
    }
    EXPECT_GT(pulses, 100) << configured_salient;
  }
}

TEST(InjectionScheduler, TheSpeedLoopsAnswerToTheReluctanceTorqueIsNoLoadChange) {
  for (const double answer : {1.0, 0.5, 0.0}) {
    double rs_error = 1.0;
    EXPECT_EQ(load_changes_rejected(4.5e-3, answer, true, &rs_error), 0) << "the answer to the pulses: " << answer;
    EXPECT_NEAR(rs_error, 0.0, 0.005) << answer;
  }
  double unused = 0.0;
  EXPECT_GE(load_changes_rejected(4.5e-3, -1.0, true, &unused), 8) << "the load moving against the answer";
  EXPECT_GE(load_changes_rejected(4.5e-3, 2.0, true, &unused), 8) << "twice the full answer";
  EXPECT_GE(load_changes_rejected(4.5e-3, 1.0, false, &unused), 8) << "a machine not configured as salient";
  EXPECT_GE(load_changes_rejected(5.5e-3, 1.0, true, &unused), 8) << "Ld = Lq: no reluctance torque to answer";
}

// Runs the first event with one of the harness's sample flags raised in every second recording.
void run_flagged_in_recording_2(Harness& h, bool Harness::*flag) {
  h.hook = [flag](Harness& x) { x.*flag = !x.records.empty() && x.records.back().out.phase == P::kRecord2; };
  h.run_until(0.45);
}

// A command the bridge clipped was not applied as recorded: the pair is rejected.
TEST(InjectionScheduler, BridgeClippingWhileRecordingRejectsThePair) {
  Harness h(test_config());
  run_flagged_in_recording_2(h, &Harness::flag_modulation_clipped);
  ASSERT_EQ(h.pairs.size(), 2U);
  for (const PairResult& p : h.pairs) {
    EXPECT_EQ(p.outcome, PairOutcome::kRejectedVoltageSaturation) << to_string(p.outcome);
  }
  EXPECT_EQ(h.estimates.at(0).outcome, EventOutcome::kNoAcceptedPairs);
}

// On the current loop's voltage limit alone the command is applied as recorded (it stays in the
// linear modulation range) and the fit takes the measured currents: the data hold, the pair is
// kept. The harness's voltages are the plant's own, as a drive's
// applied command is.
TEST(InjectionScheduler, TheLoopsVoltageLimitAloneKeepsThePair) {
  Harness h(test_config());
  run_flagged_in_recording_2(h, &Harness::flag_voltage_limited);
  ASSERT_EQ(h.pairs.size(), 2U);
  for (const PairResult& p : h.pairs) {
    EXPECT_EQ(p.outcome, PairOutcome::kAccepted) << to_string(p.outcome);
    EXPECT_TRUE(p.conditions.any_voltage_limited);
    EXPECT_FALSE(p.conditions.any_modulation_clipped);
  }
  ASSERT_EQ(h.estimates.at(0).outcome, EventOutcome::kPublished);
  EXPECT_NEAR(h.estimates.at(0).rs_ohm, h.plant.rs_ohm, 2e-4);
}

TEST(InjectionScheduler, ImplausiblePairsAreRejected) {
  InjectionConfig c = test_config();
  c.fit_dead_time = false;
  Harness h(c);
  h.plant.vx_V = 0.0;
  h.plant.rs_ohm = 0.4;  // above rs_max_ohm = 0.27
  h.run_until(0.45);
  ASSERT_EQ(h.pairs.size(), 2U);
  for (const PairResult& p : h.pairs) {
    EXPECT_EQ(p.outcome, PairOutcome::kRejectedImplausible) << to_string(p.outcome);
    EXPECT_NEAR(p.rs_ohm, 0.4, 2e-3);
  }
  EXPECT_EQ(h.estimates.at(0).outcome, EventOutcome::kNoAcceptedPairs);
}

TEST(InjectionScheduler, ImplausibleEventPublishesNothingAndKeepsThePrior) {
  // Each pair, with Vx held at the uncertain prior, passes the widened window; the event's
  // joint fit finds Rs = 0.29 ohm, outside [0.09, 0.27].
  InjectionConfig c = test_config();
  Harness h(c);
  h.plant.rs_ohm = 0.29;
  h.run_until(0.45);
  ASSERT_EQ(h.pairs.size(), 2U);
  EXPECT_EQ(h.pairs[0].outcome, PairOutcome::kAccepted) << to_string(h.pairs[0].outcome);
  EXPECT_EQ(h.pairs[1].outcome, PairOutcome::kAccepted) << to_string(h.pairs[1].outcome);
  ASSERT_EQ(h.estimates.size(), 1U);
  EXPECT_EQ(h.estimates[0].outcome, EventOutcome::kImplausible);
  EXPECT_NEAR(h.estimates[0].rs_ohm, 0.29, 2e-3);
  EXPECT_EQ(h.scheduler.vx_V(), c.vx_initial_V);
  EXPECT_EQ(h.scheduler.vx_std_V(), c.vx_initial_std_V);
}

TEST(InjectionScheduler, RequestNowStartsAnEventBeforeItsTime) {
  InjectionConfig c = test_config();
  c.first_event_s = 100.0;
  Harness h(c);
  h.run_until(0.005);
  EXPECT_EQ(h.records.back().out.phase, P::kIdle);
  h.request_now = true;
  h.step();
  h.request_now = false;
  EXPECT_EQ(h.records.back().out.phase, P::kRampUp);
  EXPECT_TRUE(h.records.back().out.active);
}

// A standing request (a calibration's) does not restart an aborted event before the retry
// delay: the shaft that reversed under it (an overhauling load) is still in that transient, and
// a new event's current would eat the voltage and current the drive needs to hold it.
TEST(InjectionScheduler, AStandingRequestWaitsTheRetryDelayAfterAnAbort) {
  InjectionConfig c = test_config();
  c.first_event_s = 100.0;
  c.retry_s = 0.5;
  Harness h(c);
  h.request_now = true;
  h.run_until(0.02);
  ASSERT_TRUE(h.records.back().out.active) << "the request did not start an event";
  h.omega_e_rad_s = -300.0;  // the shaft reverses: the angle-based pair cannot survive it
  h.step();
  ASSERT_FALSE(h.estimates.empty());
  EXPECT_EQ(h.estimates.back().outcome, EventOutcome::kAborted);
  const double aborted_at = h.records.back().time_s;
  const std::size_t after = h.records.size();
  h.run_until(aborted_at + 0.49);
  for (std::size_t k = after; k < h.records.size(); ++k) {
    ASSERT_FALSE(h.records[k].out.active) << "an event started " << h.records[k].time_s - aborted_at << " s after the abort";
  }
  h.run_until(aborted_at + 0.52);
  EXPECT_TRUE(h.records.back().out.active) << "the request is served again after the retry delay";
}

TEST(InjectionScheduler, SetConfigDropsTheEventAndKeepsTheVxPrior) {
  Harness h(test_config());
  h.run_until(0.3);
  ASSERT_EQ(h.estimates.size(), 1U);
  const double vx = h.scheduler.vx_V();
  EXPECT_NE(vx, 0.0);
  h.request_now = true;
  h.run_until(0.32);
  ASSERT_TRUE(h.records.back().out.active);
  InjectionConfig other = test_config();
  other.f_A = 20.0;
  h.scheduler.set_config(other);
  EXPECT_EQ(h.scheduler.phase(), P::kIdle);
  EXPECT_EQ(h.scheduler.vx_V(), vx);
  EXPECT_EQ(h.scheduler.config().f_A, 20.0);
}

TEST(InjectionScheduler, MethodNoneNeverInjects) {
  InjectionConfig c = test_config();
  c.method = InjectionMethod::kNone;
  Harness h(c);
  h.request_now = true;
  h.run_until(0.2);
  for (const StepRecord& r : h.records) {
    EXPECT_FALSE(r.out.active);
    EXPECT_EQ(r.out.injection_A.d, 0.0);
  }
  EXPECT_TRUE(h.pairs.empty());
  EXPECT_TRUE(h.estimates.empty());
}

TEST(InjectionScheduler, OutcomeNamesAreDistinct) {
  std::vector<std::string_view> names;
  for (int k = 0; k < static_cast<int>(PairOutcome::kCount); ++k) {
    names.push_back(to_string(static_cast<PairOutcome>(k)));
  }
  std::sort(names.begin(), names.end());
  EXPECT_EQ(std::adjacent_find(names.begin(), names.end()), names.end());
  EXPECT_EQ(to_string(EventOutcome::kPublished), "published");
  EXPECT_EQ(to_string(PairOutcome::kRejectedSpeedChange), "rejected_speed_change");
}

}  // namespace
}  // namespace pmsm::core
