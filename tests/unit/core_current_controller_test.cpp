#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

#include "pmsm/core/current_controller.hpp"
#include "pmsm/core/field_weakening.hpp"

namespace pmsm::core {
namespace {

// An ideal machine obeying Eq. 3, written here independently of core/: dq currents integrated
// with RK4 over sub-steps while the voltage applied during a period is the command computed
// one period earlier (the computation delay of a real drive).
struct IdealMachine {
  double rs = 0.133, ld = 5.5e-3, lq = 5.5e-3, psi = 0.3239;
  double omega_e = 0.0;
  double id = 0.0, iq = 0.0;

  void advance(double vd, double vq, double dt) {
    auto f = [&](double d, double q, double& dd, double& dq) {
      dd = (vd - rs * d + omega_e * lq * q) / ld;
      dq = (vq - rs * q - omega_e * ld * d - omega_e * psi) / lq;
    };
    const int sub = 20;
    const double h = dt / sub;
    for (int n = 0; n < sub; ++n) {
      double k1d, k1q, k2d, k2q, k3d, k3q, k4d, k4q;
      f(id, iq, k1d, k1q);
      f(id + 0.5 * h * k1d, iq + 0.5 * h * k1q, k2d, k2q);
      f(id + 0.5 * h * k2d, iq + 0.5 * h * k2q, k3d, k3q);
      f(id + h * k3d, iq + h * k3q, k4d, k4q);
      id += h / 6.0 * (k1d + 2 * k2d + 2 * k3d + k4d);
      iq += h / 6.0 * (k1q + 2 * k2q + 2 * k3q + k4q);
    }
  }
};

struct StepResult {
  std::vector<double> response;  // the stepped axis, one value per period
  double other_axis_peak = 0.0;
};

// Steps one axis from its initial value to `target` and records the response.
StepResult run_step(CurrentControllerConfig config, IdealMachine machine, Dq initial_ref,
                    Dq step_ref, bool step_d, int periods_before, int periods_after) {
  CurrentController controller(config);
  Dq pending{};  // the command waiting for the next period
  StepResult out;
  const double vdc = 650.0;
  for (int k = 0; k < periods_before + periods_after; ++k) {
    const Dq ref = k < periods_before ? initial_ref : step_ref;
    const Dq v = controller.step(ref, {machine.id, machine.iq}, machine.omega_e, vdc).v_V;
    machine.advance(pending.d, pending.q, config.period_s);
    pending = v;
    if (k >= periods_before) {
      out.response.push_back(step_d ? machine.id : machine.iq);
      const double other = step_d ? machine.iq - initial_ref.q : machine.id - initial_ref.d;
      out.other_axis_peak = std::max(out.other_axis_peak, std::abs(other));
    }
  }
  return out;
}

// Time for the response to cover 63.2 % of a step from `from` to `to`.
double rise_time_63_s(const std::vector<double>& r, double from, double to, double period) {
  const double threshold = from + 0.632 * (to - from);
  for (std::size_t k = 0; k < r.size(); ++k) {
    if ((to - from) * (r[k] - threshold) >= 0.0) {
      return static_cast<double>(k + 1) * period;
    }
  }
  return 1e9;
}

TEST(CurrentController, TracksDAndQStepsWithTheDesignedBandwidth) {
  CurrentControllerConfig config;
  config.bandwidth_rad_s = 2000.0;
  // 600 rad/s electrical keeps every step inside the voltage limit (EMF 194 V).
  for (double omega_e : {0.0, 600.0}) {
    IdealMachine machine;
    machine.omega_e = omega_e;
    // Settle at iq = 10 A first so the decoupling has something to decouple.
    for (bool step_d : {true, false}) {
      const Dq initial{0.0, 10.0};
      // Steps small enough that the proportional kick (Kp * step = 110 V) stays inside the
      // voltage limit: this test is about the linear design; saturation has its own test.
      const Dq target = step_d ? Dq{10.0, 10.0} : Dq{0.0, 20.0};
      const StepResult r = run_step(config, machine, initial, target, step_d, 400, 400);
      const double from = step_d ? initial.d : initial.q;
      const double to = step_d ? target.d : target.q;
      // Pole-zero cancellation leaves an integrator loop with crossover wc, so the step
      // covers 63 % in about 1/wc; the 1.5-period delay stretches that by at most 1.5 Ts.
      const double measured = rise_time_63_s(r.response, from, to, config.period_s);
      EXPECT_GE(measured, 0.9 / config.bandwidth_rad_s) << "omega_e=" << omega_e << " d=" << step_d;
      EXPECT_LE(measured, 1.0 / config.bandwidth_rad_s + 1.5 * config.period_s + 1e-9)
          << "omega_e=" << omega_e << " d=" << step_d;
      // No steady-state error.
      EXPECT_NEAR(r.response.back(), to, 1e-3 * std::abs(to - from));
      // Little overshoot.
      double peak = 0.0;
      for (double x : r.response) peak = std::max(peak, (x - from) / (to - from));
      EXPECT_LT(peak, 1.1);
      // The decoupling keeps the other axis nearly undisturbed.
      EXPECT_LT(r.other_axis_peak, 0.15 * std::abs(to - from));
    }
  }
}

// The controller's parameters off from the ideal machine's, as after commissioning.
CurrentControllerConfig commissioned_config() {
  CurrentControllerConfig config;
  config.rs_ohm = 0.12;
  config.ld_H = 6.0e-3;
  config.lq_H = 5.0e-3;
  config.flux_linkage_Wb = 0.3239 * 1.03;
  return config;
}

TEST(CurrentController, NoSteadyStateErrorWithModelMismatch) {
  const CurrentControllerConfig config = commissioned_config();
  IdealMachine machine;
  machine.omega_e = 600.0;
  machine.rs = 0.17;
  // The imperfect cancellation leaves a slow mode near Rs/L of the model (~24 rad/s): give it
  // half a second.
  const StepResult r = run_step(config, machine, {0.0, 0.0}, {-15.0, 25.0}, false, 10, 5000);
  EXPECT_NEAR(r.response.back(), 25.0, 0.01);
}

TEST(CurrentController, VoltageLimitWithDAxisPriorityAndAntiWindup) {
  CurrentControllerConfig config;
  CurrentController controller(config);
  IdealMachine machine;
  machine.omega_e = 942.0;
  const double vdc = 650.0;
  // Ask for far more q current than the bus allows at this speed.
  Dq pending{};
  bool limited_seen = false;
  for (int k = 0; k < 2000; ++k) {
    const CurrentControllerStatus& s =
        controller.step({-5.0, 300.0}, {machine.id, machine.iq}, machine.omega_e, vdc);
    EXPECT_LE(std::hypot(s.v_V.d, s.v_V.q), controller.voltage_limit_V(vdc) + 1e-9);
    limited_seen = limited_seen || s.voltage_limited;
    machine.advance(pending.d, pending.q, config.period_s);
    pending = s.v_V;
  }
  EXPECT_TRUE(limited_seen);
  // The d-axis is served first: it still tracks its reference under saturation.
  EXPECT_NEAR(machine.id, -5.0, 0.5);
  // Drop back to a reachable reference: with anti-windup the loop recovers within a few
  // time constants instead of unwinding a huge integral.
  int recovered_at = -1;
  for (int k = 0; k < 200; ++k) {
    const Dq v = controller.step({0.0, 10.0}, {machine.id, machine.iq}, machine.omega_e, vdc).v_V;
    machine.advance(pending.d, pending.q, config.period_s);
    pending = v;
    if (recovered_at < 0 && std::abs(machine.iq - 10.0) < 0.5) recovered_at = k;
  }
  EXPECT_GE(recovered_at, 0);
  EXPECT_LT(recovered_at, 50);
}

// A pulse's d current handed over at the end of a pair (DriveController::weaken_field): taken
// where it weakens more than the regulator's own, within the bound, never where it weakens
// less (a +F pulse), a NaN or disabled; afterwards the regulator is unsettled and relaxes it
// from there by its own law (below the limit, back towards zero).
TEST(FieldWeakening, TakesAPulsesCurrentOverOnlyWhereItWeakensMore) {
  FieldWeakeningConfig fw;
  fw.enabled = true;
  fw.max_current_A = 10.0;
  FieldWeakening reg(fw);
  reg.set_machine(5.5e-3, 0.3239, 1e-4);
  reg.take_over(-6.0, 80.0);
  EXPECT_EQ(reg.id_A(), -6.0);
  EXPECT_FALSE(reg.settled());
  reg.take_over(-2.0, 80.0);  // weaker than the present d current: nothing
  reg.take_over(3.0, 80.0);
  reg.take_over(std::numeric_limits<double>::quiet_NaN(), 80.0);
  EXPECT_EQ(reg.id_A(), -6.0);
  reg.take_over(-25.0, 80.0);  // the configured bound
  EXPECT_EQ(reg.id_A(), -10.0);
  reg.take_over(-25.0, 8.0);   // never back: a tighter bound is step()'s to apply
  EXPECT_EQ(reg.id_A(), -10.0);
  FieldWeakening fresh(fw);
  fresh.set_machine(5.5e-3, 0.3239, 1e-4);
  fresh.take_over(-25.0, 8.0);  // the drive's current limit, tighter than the configured bound
  EXPECT_EQ(fresh.id_A(), -8.0);
  const double after = reg.step(200.0, 356.0, 1400.0, 80.0);  // far below the held voltage
  EXPECT_GT(after, -10.0);
  EXPECT_LE(after, 0.0);
  fw.enabled = false;
  FieldWeakening disabled(fw);
  disabled.take_over(-6.0, 80.0);
  EXPECT_EQ(disabled.id_A(), 0.0);
}

}  // namespace
}  // namespace pmsm::core

namespace pmsm::core {
namespace {

struct WeakenedRun {
  double id = 0.0;           // the machine's currents at the end
  double iq = 0.0;
  double v = 0.0;            // |v*| at the end
  double limit = 0.0;
  double fw_id = 0.0;        // what the regulator asked
  bool settled = false;
  int limited_late = 0;      // periods on the voltage limit in the last half
};

// The current loop with field weakening (the drive's order: the regulator on the last period's
// command, then the loop) on the ideal machine turning at a fixed electrical speed, asked for a
// q current. The commissioned model is off from the machine, as after commissioning.
WeakenedRun run_weakened(double omega_e, double iq_ref, FieldWeakeningConfig fw_config, int periods) {
  const CurrentControllerConfig config = commissioned_config();
  IdealMachine machine;
  machine.omega_e = omega_e;
  CurrentController controller(config);
  FieldWeakening fw(fw_config);
  fw.set_machine(config.ld_H, config.flux_linkage_Wb, config.period_s);
  const double vdc = 650.0;
  Dq pending{};
  WeakenedRun out;
  for (int k = 0; k < periods; ++k) {
    const CurrentControllerStatus& last = controller.status();
    const double id_ref = fw.step(std::hypot(last.v_unlimited_V.d, last.v_unlimited_V.q), last.voltage_limit_V,
                                  omega_e, 80.0);
    const CurrentControllerStatus& s = controller.step({id_ref, iq_ref}, {machine.id, machine.iq}, omega_e, vdc);
    machine.advance(pending.d, pending.q, config.period_s);
    pending = s.v_V;
    if (k >= periods / 2 && s.voltage_limited) {
      ++out.limited_late;
    }
    out.v = std::hypot(s.v_unlimited_V.d, s.v_unlimited_V.q);
    out.limit = s.voltage_limit_V;
  }
  out.id = machine.id;
  out.iq = machine.iq;
  out.fw_id = fw.id_A();
  out.settled = fw.settled();
  return out;
}

// Below the speed where the EMF takes the voltage (Table I at 650 V: 356 V over psi = 0.3239 Wb,
// 1100 rad/s electrical), the regulator asks nothing: id = 0 control, untouched.
TEST(FieldWeakening, AsksNothingBelowTheVoltageLimit) {
  FieldWeakeningConfig fw;
  fw.enabled = true;
  fw.max_current_A = 55.0;
  const WeakenedRun r = run_weakened(600.0, 30.0, fw, 4000);
  EXPECT_EQ(r.fw_id, 0.0);
  EXPECT_TRUE(r.settled);
  EXPECT_NEAR(r.iq, 30.0, 0.05);
}

// Above it, id = 0 control cannot deliver the q current (the EMF alone exceeds the limit) and
// the regulator finds the d current at which the machine's voltage is the held share of the
// limit: the one Eq. 3 gives in the steady state, with the machine's own parameters.
TEST(FieldWeakening, HoldsTheVoltageAndDeliversTheTorqueCurrentAboveBaseSpeed) {
  const double omega_e = 1400.0;  // EMF 453 V on the machine's psi, against a 356 V limit
  const double iq_ref = 20.0;
  FieldWeakeningConfig off;
  off.enabled = false;
  const WeakenedRun without = run_weakened(omega_e, iq_ref, off, 6000);
  // Without it the loop sits on the limit and the q current is far from its reference.
  EXPECT_GT(without.limited_late, 2000);
  EXPECT_LT(without.iq, 0.5 * iq_ref);

  FieldWeakeningConfig on;
  on.enabled = true;
  on.max_current_A = 55.0;
  const WeakenedRun with = run_weakened(omega_e, iq_ref, on, 6000);
  EXPECT_EQ(with.limited_late, 0);
  EXPECT_TRUE(with.settled);
  EXPECT_NEAR(with.iq, iq_ref, 0.01 * iq_ref);
  EXPECT_NEAR(with.v, on.voltage_fraction * with.limit, 0.5);
  // The steady state of the machine (rs 0.133, ld = lq = 5.5 mH, psi 0.3239): the id that puts
  // |v| = |(rs id - w lq iq, rs iq + w (psi + ld id))| on the held voltage, by bisection.
  const IdealMachine m;
  const double target = on.voltage_fraction * with.limit;
  auto voltage = [&](double id) {
    return std::hypot(m.rs * id - omega_e * m.lq * iq_ref, m.rs * iq_ref + omega_e * (m.psi + m.ld * id));
  };
  double lo = -55.0, hi = 0.0;  // voltage(lo) < target < voltage(hi)
  for (int k = 0; k < 60; ++k) {
    const double mid = 0.5 * (lo + hi);
    (voltage(mid) > target ? hi : lo) = mid;
  }
  EXPECT_NEAR(with.id, lo, 0.2);
  EXPECT_NEAR(with.fw_id, with.id, 0.2);
}

// The d current stays within its bound: asked for more than it allows, the regulator rests on
// it (and says it is settled there: nothing more will move), and the loop is back on its limit.
TEST(FieldWeakening, StaysWithinItsBound) {
  FieldWeakeningConfig fw;
  fw.enabled = true;
  fw.max_current_A = 10.0;
  const WeakenedRun r = run_weakened(1400.0, 20.0, fw, 6000);
  EXPECT_EQ(r.fw_id, -10.0);
  EXPECT_TRUE(r.settled);
  EXPECT_GT(r.limited_late, 2000);
  // A bound that shrinks (a derating) takes the current with it at once; a NaN voltage moves
  // nothing; disabled, it asks nothing.
  FieldWeakening reg(fw);
  reg.set_machine(5.5e-3, 0.3239, 1e-4);
  for (int k = 0; k < 2000; ++k) reg.step(400.0, 356.0, 1400.0, 80.0);
  EXPECT_EQ(reg.id_A(), -10.0);
  EXPECT_EQ(reg.step(400.0, 356.0, 1400.0, 4.0), -4.0);
  EXPECT_EQ(reg.step(std::numeric_limits<double>::quiet_NaN(), 356.0, 1400.0, 4.0), -4.0);
  fw.enabled = false;
  FieldWeakening disabled(fw);
  disabled.set_machine(5.5e-3, 0.3239, 1e-4);
  EXPECT_EQ(disabled.step(400.0, 356.0, 1400.0, 80.0), 0.0);
}

}  // namespace
}  // namespace pmsm::core
