#include <gtest/gtest.h>

#include <cmath>

#include "pmsm/core/injection.hpp"
#include "pmsm/core/machine_equations.hpp"

namespace pmsm::core {
namespace {

// Eq. 3 evaluated with a numerical time derivative of the rotor-frame currents: the reference
// the injection voltage formulas are checked against.
template <typename CurrentOfTime>
Dq eq3_numeric(CurrentOfTime current, double t, double rs, double ld, double lq, double omega_e) {
  const double h = 1e-8;
  const Dq i = current(t);
  const Dq ip = current(t + h);
  const Dq im = current(t - h);
  const double did = (ip.d - im.d) / (2 * h);
  const double diq = (ip.q - im.q) / (2 * h);
  return {rs * i.d - omega_e * lq * i.q + ld * did, omega_e * ld * i.d + rs * i.q + lq * diq};
}

TEST(DcInjection, StatorAndRotorViewsAgree) {
  const double f = 25.0;
  const double theta_f = 0.4;
  for (double theta : {0.0, 1.0, 2.5, 5.0}) {
    const Dq from_stator = park(dc_injection_current_stator(f, theta_f), theta);  // Eqs. 4-5
    const Dq rotor = dc_injection_current_rotor(f, theta_f, theta);              // Eqs. 6-7
    EXPECT_NEAR(from_stator.d, rotor.d, 1e-12);
    EXPECT_NEAR(from_stator.q, rotor.q, 1e-12);
  }
}

TEST(DcInjection, VoltageMatchesEq3) {
  const double f = 25.0, theta_f = 0.3, rs = 0.133;
  for (double lq : {5.5e-3, 8.25e-3}) {
    const double ld = 5.5e-3;
    const double omega_e = 900.0;
    auto current = [&](double t) { return dc_injection_current_rotor(f, theta_f, omega_e * t); };
    for (double t : {0.0002, 0.0011, 0.0043}) {
      const Dq expected = eq3_numeric(current, t, rs, ld, lq, omega_e);
      const Dq v = dc_injection_voltage_rotor(f, theta_f, omega_e * t, rs, ld, lq, omega_e);
      EXPECT_NEAR(v.d, expected.d, 1e-5);
      EXPECT_NEAR(v.q, expected.q, 1e-5);
    }
  }
  // Round rotor: the stator-fixed current needs only the resistive voltage |V| = F Rs.
  const Dq v = dc_injection_voltage_rotor(f, theta_f, 1.7, rs, 5.5e-3, 5.5e-3, 900.0);
  EXPECT_NEAR(std::hypot(v.d, v.q), f * rs, 1e-12);
}

TEST(DcInjection, MakesTorqueRipple) {
  // Eq. 10 with Eq. 7: the q-axis part of a stator-fixed vector makes torque that alternates
  // at the electrical frequency (the reason for d-axis injection).
  const double f = 25.0;
  double t_min = 1e9, t_max = -1e9;
  for (int k = 0; k < 360; ++k) {
    const double theta = k * kTwoPi / 360.0;
    const double t = electromagnetic_torque_Nm(0.3239, 5.5e-3, 5.5e-3, 3,
                                               dc_injection_current_rotor(f, 0.0, theta));
    t_min = std::min(t_min, t);
    t_max = std::max(t_max, t);
  }
  EXPECT_NEAR(t_max, 1.5 * 3 * 0.3239 * f, 1e-3);
  EXPECT_NEAR(t_min, -1.5 * 3 * 0.3239 * f, 1e-3);
}

TEST(FixedAngle, ZeroTorqueForBetaZeroWithRoundRotor) {
  const double psi = 0.3239;
  const double kt = 1.5 * 3 * psi;
  const double iq_motoring = 20.0;
  for (int k = 0; k < 36; ++k) {
    const double theta = k * kTwoPi / 36.0;
    const Dq inj = fixed_angle_injection_current(30.0, 0.0, 0.0, theta);  // Eqs. 11-12, beta = 0
    EXPECT_EQ(inj.q, 0.0);
    EXPECT_EQ(fixed_angle_injection_torque_Nm(30.0, 0.0, 0.0, kt, theta), 0.0);  // Eq. 13
    // The full torque with the injection superposed on the motoring current is unchanged.
    const double with = electromagnetic_torque_Nm(psi, 5.5e-3, 5.5e-3, 3, {inj.d, iq_motoring});
    const double without = electromagnetic_torque_Nm(psi, 5.5e-3, 5.5e-3, 3, {0.0, iq_motoring});
    EXPECT_NEAR(with, without, 1e-12);
  }
  // beta = 1 is DC injection: Eq. 13 equals Kt times Eq. 7.
  EXPECT_NEAR(fixed_angle_injection_torque_Nm(30.0, 0.2, 1.0, kt, 1.0),
              kt * dc_injection_current_rotor(30.0, 0.2, 1.0).q, 1e-12);
}

TEST(FixedAngle, ArcOf30DegreesChangesMagnitudeBy3Point4Percent) {
  EXPECT_NEAR(fixed_angle_magnitude_change_over_arc(30.0 * kPi / 180.0, 0.0), 0.034, 0.0005);
  EXPECT_NEAR(fixed_angle_magnitude_change_over_arc(30.0 * kPi / 180.0, 1.0), 0.0, 1e-12);
}

TEST(FixedAngle, VoltageMatchesEq3) {
  const double f = 30.0, theta_f = 1.2, rs = 0.15, ld = 5e-3, omega_e = 700.0;
  auto current = [&](double t) { return fixed_angle_injection_current(f, theta_f, 0.0, omega_e * t); };
  for (double t : {0.0005, 0.0017, 0.003}) {
    const Dq expected = eq3_numeric(current, t, rs, ld, 7e-3, omega_e);  // Lq irrelevant: iq = 0
    const Dq v = fixed_angle_injection_voltage(f, theta_f, omega_e * t, rs, ld, omega_e);
    EXPECT_NEAR(v.d, expected.d, 1e-5);
    EXPECT_NEAR(v.q, expected.q, 1e-5);
  }
}

TEST(SignalResolution, Eq22RecoversComponentsAlongNonOrthogonalDirections) {
  const double vr = 3.7, vl = 41.0, theta_r = 0.5, theta_l = 1.6;
  const double x = vr * std::cos(theta_r) + vl * std::cos(theta_l);
  const double y = vr * std::sin(theta_r) + vl * std::sin(theta_l);
  const ResolvedSignal s = resolve_signal_voltage(std::hypot(x, y), std::atan2(y, x), theta_r, theta_l);
  EXPECT_NEAR(s.vr_V, vr, 1e-9);
  EXPECT_NEAR(s.vl_V, vl, 1e-9);
  EXPECT_NEAR(resolution_conditioning(theta_r, theta_l), std::sin(1.1), 1e-12);
  EXPECT_NEAR(resolution_conditioning(0.3, 0.3 + kPi), 0.0, 1e-12);
}

TEST(SignalResolution, FixedAngleInjectionVoltagesResolveToFRsAndWFLd) {
  // Drive the fixed-angle voltage (Eqs. 14-15, in the rotor frame) into the stator frame and
  // resolve it with Eq. 22 along the directions the method predicts: the resistive part is
  // F Rs cos(thF - th), the inductive part w F Ld, at every angle of a 30 degree arc.
  const double f = 40.0, theta_f = 2.0, rs = 0.133, ld = 5.5e-3, omega_e = 942.0;
  for (double offset_deg = -15.0; offset_deg <= 15.0; offset_deg += 5.0) {
    const double theta = theta_f + offset_deg * kPi / 180.0;
    const Dq v_rotor = fixed_angle_injection_voltage(f, theta_f, theta, rs, ld, omega_e);
    const AlphaBeta v = inverse_park(v_rotor, theta);
    const SignalDirections dir = fixed_angle_signal_directions(theta_f, theta);
    const ResolvedSignal s = resolve_signal_voltage(std::hypot(v.alpha, v.beta),
                                                    std::atan2(v.beta, v.alpha), dir.theta_r_rad,
                                                    dir.theta_l_rad);
    EXPECT_NEAR(s.vr_V, f * rs * std::cos(theta_f - theta), 1e-9);
    EXPECT_NEAR(s.vl_V, omega_e * f * ld, 1e-9);
  }
}

TEST(FixedMagnitude, CurrentsAndOrthogonalVoltages) {
  const double f = 25.0, rs = 0.133, ld = 5.5e-3, omega_e = 942.0;
  for (double theta : {0.0, 0.8, 3.0}) {
    const Dq from_stator = park(fixed_magnitude_injection_current_stator(f, theta), theta);
    EXPECT_NEAR(from_stator.d, f, 1e-12);  // Eq. 18
    EXPECT_NEAR(from_stator.q, 0.0, 1e-12);  // Eq. 19
  }
  const Dq v = fixed_magnitude_injection_voltage(f, rs, ld, omega_e);
  // Eqs. 20-21 against Eq. 3 with a constant idr = F.
  const Dq expected = eq3_numeric([&](double) { return Dq{f, 0.0}; }, 0.0, rs, ld, 9e-3, omega_e);
  EXPECT_NEAR(v.d, expected.d, 1e-9);
  EXPECT_NEAR(v.q, expected.q, 1e-9);
  // The resistive voltage vector (on d) is orthogonal to the inductive one and to the EMF
  // (both on q): their dot products vanish.
  const Dq resistive{v.d, 0.0};
  const Dq inductive{0.0, v.q};
  const Dq emf{0.0, 0.97 * 314.0};
  EXPECT_EQ(resistive.d * inductive.d + resistive.q * inductive.q, 0.0);
  EXPECT_EQ(resistive.d * emf.d + resistive.q * emf.q, 0.0);
  EXPECT_NEAR(v.d, f * rs, 1e-12);
}

TEST(Budget, Eq29AndFig8) {
  // Fig. 8: Ld = 9 mH, Rs = 0.133 ohm. Numbers computed here from the paper's constants.
  const double ld = 9e-3, rs = 0.133;
  for (double tw : {0.005, 0.01, 0.03, 0.05}) {
    for (double f : {25.0, 50.0, 75.0}) {
      const double expected_b = f * std::sqrt(std::pow(1.81 * ld / tw, 2) + rs * rs);
      const double expected_b2 = f * std::sqrt(std::pow(2.04 * ld / tw, 2) + rs * rs);
      EXPECT_NEAR(required_injection_voltage_V(f, ld, rs, tw, WindowKind::kBlackman) / expected_b, 1.0, 0.003);
      EXPECT_NEAR(required_injection_voltage_V(f, ld, rs, tw, WindowKind::kModifiedBlackman) / expected_b2, 1.0, 0.003);
      // The inverse gives back F.
      EXPECT_NEAR(max_injection_current_A(expected_b, ld, rs, tw, WindowKind::kBlackman) / f, 1.0, 0.003);
    }
  }
  // A point read off Fig. 8: 25 A with Tw = 10 ms needs about 41 V.
  EXPECT_NEAR(required_injection_voltage_V(25.0, ld, rs, 0.01, WindowKind::kBlackman), 40.9, 0.3);
  EXPECT_NEAR(per_phase_injection_current_A(75.0), 50.0, 1e-12);  // Eq. 30
}

TEST(Budget, HeadroomAtAnOperatingPointTouchesTheLimit) {
  InjectionHeadroomInput in;
  in.omega_e_rad_s = 600.0;
  in.iq_A = 20.0;
  in.voltage_limit_V = 0.95 * 650.0 / std::sqrt(3.0);
  for (double polarity : {1.0, -1.0}) {
    const double f = max_injection_current_at_operating_point_A(in, polarity);
    ASSERT_GT(f, 0.0);
    // At F the worst-case voltage (computed here from Eq. 3 and Eq. 29 terms) is on the circle.
    const double k = 1.81;
    const double vd = in.rs_ohm * in.id_A - in.omega_e_rad_s * in.lq_H * in.iq_A +
                      polarity * f * std::sqrt(std::pow(k * in.ld_H / in.tw_s, 2) + in.rs_ohm * in.rs_ohm);
    const double vq = in.rs_ohm * in.iq_A + in.omega_e_rad_s * in.flux_linkage_Wb +
                      polarity * in.omega_e_rad_s * in.ld_H * f;
    EXPECT_NEAR(std::hypot(vd, vq) / in.voltage_limit_V, 1.0, 0.003) << polarity;
  }
  // Positive d current raises the q-axis voltage at speed, so it affords less than negative.
  EXPECT_LT(max_injection_current_at_operating_point_A(in, 1.0),
            max_injection_current_at_operating_point_A(in, -1.0));
  // No headroom at all beyond the speed where the EMF alone fills the circle.
  in.omega_e_rad_s = 1200.0;
  EXPECT_EQ(max_injection_current_at_operating_point_A(in, 1.0), 0.0);
  // At standstill with no load it reduces to Eq. 29 inverted.
  in.omega_e_rad_s = 0.0;
  in.iq_A = 0.0;
  EXPECT_NEAR(max_injection_current_at_operating_point_A(in, 1.0),
              max_injection_current_A(in.voltage_limit_V, in.ld_H, in.rs_ohm, in.tw_s, in.window), 1e-9);
}

// |(id + s F, iq)| within the limit: a 3-4-5 triangle; a motoring id takes from one polarity's
// room and gives to the other's; nothing (never less) where iq alone reaches the limit.
TEST(Budget, CurrentLimitLeavesTheRestOfTheCircle) {
  EXPECT_DOUBLE_EQ(max_injection_current_for_current_limit_A(50.0, 0.0, 30.0, 1.0), 40.0);
  EXPECT_DOUBLE_EQ(max_injection_current_for_current_limit_A(50.0, 0.0, -30.0, -1.0), 40.0);
  EXPECT_DOUBLE_EQ(max_injection_current_for_current_limit_A(50.0, -10.0, 30.0, 1.0), 50.0);
  EXPECT_DOUBLE_EQ(max_injection_current_for_current_limit_A(50.0, -10.0, 30.0, -1.0), 30.0);
  EXPECT_EQ(max_injection_current_for_current_limit_A(50.0, 0.0, 50.0, 1.0), 0.0);
  EXPECT_EQ(max_injection_current_for_current_limit_A(50.0, 0.0, 60.0, -1.0), 0.0);
  EXPECT_EQ(max_injection_current_for_current_limit_A(50.0, -45.0, 30.0, -1.0), 0.0);
  // A turning vector (fixed-angle, DC) points every way in turn: limit - |(id, iq)|.
  EXPECT_DOUBLE_EQ(max_injection_current_for_current_limit_A(50.0, 30.0, 40.0, 1.0, true), 0.0);
  EXPECT_DOUBLE_EQ(max_injection_current_for_current_limit_A(65.0, 0.0, 25.0, -1.0, true), 40.0);
  EXPECT_EQ(max_injection_current_for_current_limit_A(50.0, 0.0, 60.0, 1.0, true), 0.0);
}

TEST(Losses, Eqs31And32WithHandComputedNumbers) {
  InjectionSchedule s;
  s.f_A = 25.0; s.rs_ohm = 0.133; s.pulses = 3; s.elapsed_s = 10.0; s.ti_s = 0.2; s.tw_s = 0.01;
  s.window = WindowKind::kBlackman;
  // Eq. 32: 25^2 * 3 * 0.133 / 10 * (0.2 + 0.84 * 0.01) = 5.1979 W.
  EXPECT_NEAR(fixed_magnitude_average_loss_W(s), 625.0 * 3 * 0.133 / 10.0 * (0.2 + 0.0084), 0.01);
  s.window = WindowKind::kModifiedBlackman;
  EXPECT_NEAR(fixed_magnitude_average_loss_W(s), 625.0 * 3 * 0.133 / 10.0 * (0.2 + 0.0125), 0.01);
  // Eq. 31 at w = 300 rad/s: bracket 2/300 sin(30) + 0.84 Tw.
  s.window = WindowKind::kBlackman;
  EXPECT_NEAR(fixed_angle_average_loss_W(s, 300.0),
              625.0 * 3 * 0.133 / 10.0 * (2.0 / 300.0 * std::sin(30.0) + 0.0084), 0.01);
  // At w -> 0 fixed-angle and fixed-magnitude coincide.
  EXPECT_NEAR(fixed_angle_average_loss_W(s, 0.0), fixed_magnitude_average_loss_W(s), 1e-12);
}

TEST(Losses, ExactFormsMatchBruteForceDissipation) {
  // Simulate three pulses in 10 s and integrate the copper loss 3/2 Rs (id^2 + iq^2) of the
  // injected current directly, sample by sample.
  InjectionSchedule s;
  s.f_A = 50.0; s.rs_ohm = 0.15; s.pulses = 3; s.elapsed_s = 10.0; s.ti_s = 0.05; s.tw_s = 0.008;
  s.window = WindowKind::kModifiedBlackman;
  const PulseEnvelope env{s.window, s.tw_s, s.ti_s};
  const double dt = 1e-6;
  double energy_fm = 0.0, energy_fa = 0.0;
  const double omega_e = 400.0;
  const double t_centre = 0.5 * env.duration_s();
  for (double t = 0.0; t < env.duration_s(); t += dt) {
    const double i_fm = s.f_A * env.value(t);
    const double i_fa = s.f_A * env.value(t) * std::cos(omega_e * (t - t_centre));
    energy_fm += 1.5 * s.rs_ohm * i_fm * i_fm * dt;
    energy_fa += 1.5 * s.rs_ohm * i_fa * i_fa * dt;
  }
  EXPECT_NEAR(fixed_magnitude_average_loss_exact_W(s) / (energy_fm * 3 / 10.0), 1.0, 1e-3);
  EXPECT_NEAR(fixed_angle_average_loss_exact_W(s, omega_e) / (energy_fa * 3 / 10.0), 1.0, 1e-3);
}

}  // namespace
}  // namespace pmsm::core
