#include "pmsm/core/injection.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace pmsm::core {
namespace {

double window_slope_constant(WindowKind kind) {
  return window_constants(kind).max_slope_times_tw;
}

}  // namespace

AlphaBeta dc_injection_current_stator(double f_A, double theta_f_rad) {
  return {f_A * std::cos(theta_f_rad), f_A * std::sin(theta_f_rad)};  // Eqs. 4-5
}

Dq dc_injection_current_rotor(double f_A, double theta_f_rad, double theta_rad) {
  const double a = theta_f_rad - theta_rad;
  return {f_A * std::cos(a), f_A * std::sin(a)};  // Eqs. 6-7
}

Dq dc_injection_voltage_rotor(double f_A, double theta_f_rad, double theta_rad, double rs_ohm,
                              double ld_H, double lq_H, double omega_e_rad_s) {
  // Eq. 3 with Eqs. 6-7: did/dt = w F sin(a), diq/dt = -w F cos(a), a = thF - th.
  const double a = theta_f_rad - theta_rad;
  const double inductive = omega_e_rad_s * f_A * (ld_H - lq_H);
  return {f_A * rs_ohm * std::cos(a) + inductive * std::sin(a),
          f_A * rs_ohm * std::sin(a) + inductive * std::cos(a)};
}

Dq fixed_angle_injection_current(double f_A, double theta_f_rad, double beta, double theta_rad) {
  const double a = theta_f_rad - theta_rad;
  return {f_A * std::cos(a), beta * f_A * std::sin(a)};  // Eqs. 11-12
}

double fixed_angle_injection_torque_Nm(double f_A, double theta_f_rad, double beta,
                                       double kt_dq_Nm_per_A, double theta_rad) {
  return beta * f_A * kt_dq_Nm_per_A * std::sin(theta_f_rad - theta_rad);  // Eq. 13
}

Dq fixed_angle_injection_voltage(double f_A, double theta_f_rad, double theta_rad, double rs_ohm,
                                 double ld_H, double omega_e_rad_s) {
  // Eq. 3 with Eq. 11 and iqr = 0 (beta = 0).
  const double a = theta_f_rad - theta_rad;
  const double vl = omega_e_rad_s * f_A * ld_H;
  return {f_A * rs_ohm * std::cos(a) + vl * std::sin(a), vl * std::cos(a)};
}

double fixed_angle_magnitude_change_over_arc(double arc_rad, double beta) {
  // |i| = F sqrt(cos^2 a + beta^2 sin^2 a); at the arc's ends a = +-arc/2.
  const double a = 0.5 * arc_rad;
  const double c = std::cos(a);
  const double s = std::sin(a);
  return 1.0 - std::sqrt(c * c + beta * beta * s * s);
}

AlphaBeta fixed_magnitude_injection_current_stator(double f_A, double theta_rad) {
  return {f_A * std::cos(theta_rad), f_A * std::sin(theta_rad)};  // Eqs. 16-17
}

Dq fixed_magnitude_injection_current(double f_A) { return {f_A, 0.0}; }  // Eqs. 18-19

Dq fixed_magnitude_injection_voltage(double f_A, double rs_ohm, double ld_H, double omega_e_rad_s) {
  return {f_A * rs_ohm, omega_e_rad_s * f_A * ld_H};  // Eqs. 20-21
}

ResolvedSignal resolve_signal_voltage(double vqds_V, double theta_qds_rad, double theta_r_rad,
                                      double theta_l_rad) {
  // Eq. 22.
  const double denominator = std::sin(theta_r_rad - theta_l_rad);
  return {-vqds_V * std::sin(theta_l_rad - theta_qds_rad) / denominator,
          vqds_V * std::sin(theta_r_rad - theta_qds_rad) / denominator};
}

double resolution_conditioning(double theta_r_rad, double theta_l_rad) {
  return std::abs(std::sin(theta_r_rad - theta_l_rad));
}

SignalDirections fixed_angle_signal_directions(double theta_f_rad, double theta_rad) {
  const double a = theta_f_rad - theta_rad;
  // Resistive voltage F Rs cos(a) on the d-axis; inductive w F Ld (sin a, cos a) in dq, whose
  // rotor-frame angle is pi/2 - a.
  return {theta_rad, theta_rad + 0.5 * kPi - a};
}

double required_injection_voltage_V(double f_A, double ld_H, double rs_ohm, double tw_s,
                                    WindowKind kind) {
  const double inductive = window_slope_constant(kind) * ld_H / tw_s;
  return f_A * std::sqrt(inductive * inductive + rs_ohm * rs_ohm);  // Eq. 29
}

double max_injection_current_A(double headroom_V, double ld_H, double rs_ohm, double tw_s,
                               WindowKind kind) {
  return headroom_V / required_injection_voltage_V(1.0, ld_H, rs_ohm, tw_s, kind);
}

double default_window_period_s(double f_A, double ld_H, double phase_voltage_limit_V, WindowKind kind) {
  constexpr double kEdgeShareOfLimit = 0.5;
  const double tw_s = window_slope_constant(kind) * ld_H * f_A / (kEdgeShareOfLimit * phase_voltage_limit_V);
  return std::isnan(tw_s) ? kPaperWindowPeriod_s : std::clamp(tw_s, kPaperWindowPeriod_s, kMaxWindowPeriod_s);
}

Dq motoring_voltage(const InjectionHeadroomInput& in) {
  return {in.rs_ohm * in.id_A - in.omega_e_rad_s * in.lq_H * in.iq_A + in.motoring_voltage_error_V.d,
          in.rs_ohm * in.iq_A + in.omega_e_rad_s * (in.ld_H * in.id_A + in.flux_linkage_Wb) +
              in.motoring_voltage_error_V.q};
}

namespace {
// |v0 + F u|^2 = limit^2 with u the worst-case voltage per ampere of one polarity (Eq. 29 on
// the d-axis, w Ld on the q-axis): |u|^2 F^2 + 2 (v0.u) F + |v0|^2 - limit^2 = 0.
struct HeadroomQuadratic {
  double a, b, c;
};

HeadroomQuadratic headroom_quadratic(const InjectionHeadroomInput& in, double polarity) {
  const Dq v0 = motoring_voltage(in);
  const double ud = polarity * required_injection_voltage_V(1.0, in.ld_H, in.rs_ohm, in.tw_s, in.window);
  const double uq = polarity * in.omega_e_rad_s * in.ld_H;
  return {ud * ud + uq * uq, v0.d * ud + v0.q * uq,
          v0.d * v0.d + v0.q * v0.q - in.voltage_limit_V * in.voltage_limit_V};
}
}  // namespace

double max_injection_current_at_operating_point_A(const InjectionHeadroomInput& in,
                                                  double polarity) {
  const HeadroomQuadratic q = headroom_quadratic(in, polarity);
  if (q.c >= 0.0) {
    return 0.0;  // the motoring voltage alone is at or beyond the limit
  }
  // c < 0, so the discriminant is positive: the positive root.
  return (-q.b + std::sqrt(q.b * q.b - q.a * q.c)) / q.a;
}

InjectionCurrentRange injection_current_range_at_operating_point_A(const InjectionHeadroomInput& in,
                                                                   double polarity) {
  const auto [a, b, c] = headroom_quadratic(in, polarity);
  // |v0 + F u|^2 <= limit^2 between the two roots.
  const double disc = b * b - a * c;
  InjectionCurrentRange r;
  if (!(a > 0.0) || !(disc >= 0.0)) {
    return r;
  }
  const double root = std::sqrt(disc);
  r.hi_A = (-b + root) / a;
  // The other root as c / (a hi): the difference -b - root loses its digits near the limit.
  r.lo_A = c > 0.0 && r.hi_A > 0.0 ? c / (a * r.hi_A) : 0.0;
  r.valid = r.hi_A > r.lo_A;
  return r;
}

double per_phase_injection_current_A(double f_A) { return 2.0 / 3.0 * f_A; }  // Eq. 30

double fixed_magnitude_average_loss_W(const InjectionSchedule& s) {
  const double c = window_constants(s.window).integral_per_tw;
  return s.f_A * s.f_A * s.pulses * s.rs_ohm / s.elapsed_s * (s.ti_s + c * s.tw_s);  // Eq. 32
}

double fixed_angle_average_loss_W(const InjectionSchedule& s, double omega_e_rad_s) {
  const double c = window_constants(s.window).integral_per_tw;
  // Eq. 31; the flat-top term tends to Ti as w -> 0.
  const double flat = std::abs(omega_e_rad_s) > 1e-9
                          ? 2.0 / omega_e_rad_s * std::sin(omega_e_rad_s * s.ti_s / 2.0)
                          : s.ti_s;
  return s.f_A * s.f_A * s.pulses * s.rs_ohm / s.elapsed_s * (flat + c * s.tw_s);
}

double fixed_magnitude_average_loss_exact_W(const InjectionSchedule& s) {
  const double c2 = window_constants(s.window).integral_squared_per_tw;
  return 1.5 * s.f_A * s.f_A * s.rs_ohm * s.pulses / s.elapsed_s * (s.ti_s + c2 * s.tw_s);
}

double fixed_angle_average_loss_exact_W(const InjectionSchedule& s, double omega_e_rad_s) {
  // The pulse is centred on theta_f: i_d(t) = F env(t) cos(w (t - t_c)), i_q = 0 (beta = 0).
  const PulseEnvelope envelope{s.window, s.tw_s, s.ti_s};
  const double t_centre = 0.5 * envelope.duration_s();
  constexpr int kIntervals = 20000;  // even
  const double h = envelope.duration_s() / kIntervals;
  double sum = 0.0;
  for (int n = 0; n <= kIntervals; ++n) {
    const double t = n * h;
    const double weight = (n == 0 || n == kIntervals) ? 1.0 : (n % 2 == 1 ? 4.0 : 2.0);
    const double i = envelope.value(t) * std::cos(omega_e_rad_s * (t - t_centre));
    sum += weight * i * i;
  }
  const double integral_s = sum * h / 3.0;
  return 1.5 * s.f_A * s.f_A * s.rs_ohm * s.pulses / s.elapsed_s * integral_s;
}

double max_injection_current_for_torque_A(double budget_Nm, int pole_pairs, double ld_H, double lq_H,
                                          double iq_A) {
  const double saliency = 1.5 * pole_pairs * std::abs(ld_H - lq_H) * std::abs(iq_A);  // Nm per A of F
  if (!(budget_Nm > 0.0) || !(saliency > 0.0)) {
    return std::numeric_limits<double>::infinity();
  }
  return budget_Nm / saliency;
}

double max_injection_current_for_current_limit_A(double limit_A, double id_A, double iq_A, double polarity,
                                                 bool turning_vector) {
  if (turning_vector) {
    return std::max(0.0, limit_A - std::hypot(id_A, iq_A));
  }
  const double room_sq = limit_A * limit_A - iq_A * iq_A;
  const double s = polarity >= 0.0 ? 1.0 : -1.0;
  return room_sq > 0.0 ? std::max(0.0, std::sqrt(room_sq) - s * id_A) : 0.0;
}

}  // namespace pmsm::core
