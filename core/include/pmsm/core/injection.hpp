// Current-injection profiles and what they cost, Sections IV-VIII of the paper.
//
// theta is the electrical rotor angle, theta_f the angle of a stator-fixed injection vector,
// F its magnitude (amplitude-invariant, phase peak amperes).
//
// Note on Eqs. 8, 9 and 14: substituting Eqs. 6-7 (or 11) into Eq. 3 gives the inductive
// term with the opposite sign to the one printed; with Ld = Lq a current that is constant in
// the stator frame induces no inductive voltage, which the printed forms contradict. The
// functions below implement the forms derived from Eq. 3 (tests compare them with a
// numerical evaluation of Eq. 3); docs/equations.md shows the derivation.
#pragma once

#include <string_view>

#include "pmsm/core/transforms.hpp"
#include "pmsm/core/window.hpp"

namespace pmsm::core {

// ---- DC injection (Section IV) ----

// Eqs. 4-5: the injected vector in the stator frame.
[[nodiscard]] AlphaBeta dc_injection_current_stator(double f_A, double theta_f_rad);

// Eqs. 6-7: the same vector seen from the rotor, rotating backwards.
[[nodiscard]] Dq dc_injection_current_rotor(double f_A, double theta_f_rad, double theta_rad);

// Eqs. 8-9 (derived from Eq. 3, see above): vdr = F Rs cos(thF - th) + w F (Ld - Lq) sin(thF - th),
// vqr = F Rs sin(thF - th) + w F (Ld - Lq) cos(thF - th).
[[nodiscard]] Dq dc_injection_voltage_rotor(double f_A, double theta_f_rad, double theta_rad,
                                            double rs_ohm, double ld_H, double lq_H,
                                            double omega_e_rad_s);

// ---- Fixed-angle injection (Section V-A) ----

// Eqs. 11-12: idr = F cos(thF - th), iqr = beta F sin(thF - th).
[[nodiscard]] Dq fixed_angle_injection_current(double f_A, double theta_f_rad, double beta,
                                               double theta_rad);

// Eq. 13: the pulsating torque the q-axis part makes, Tem = beta F Kt sin(thF - th).
[[nodiscard]] double fixed_angle_injection_torque_Nm(double f_A, double theta_f_rad, double beta,
                                                     double kt_dq_Nm_per_A, double theta_rad);

// Eqs. 14-15 (beta = 0; derived from Eq. 3, see above):
// vdr = F Rs cos(thF - th) + w F Ld sin(thF - th),  vqr = w F Ld cos(thF - th).
[[nodiscard]] Dq fixed_angle_injection_voltage(double f_A, double theta_f_rad, double theta_rad,
                                               double rs_ohm, double ld_H, double omega_e_rad_s);

// Relative change of the injected current magnitude over an arc centred on theta_f
// (Section VI-A: 3.4 % for a 30 degree arc with beta = 0).
[[nodiscard]] double fixed_angle_magnitude_change_over_arc(double arc_rad, double beta);

// ---- Fixed-magnitude injection (Section V-B) ----

// Eqs. 16-17: ids = F cos(th), iqs = F sin(th).
[[nodiscard]] AlphaBeta fixed_magnitude_injection_current_stator(double f_A, double theta_rad);

// Eqs. 18-19: idr = F, iqr = 0.
[[nodiscard]] Dq fixed_magnitude_injection_current(double f_A);

// Eqs. 20-21: vdr = F Rs, vqr = w F Ld (resistive on d, inductive on q: orthogonal).
[[nodiscard]] Dq fixed_magnitude_injection_voltage(double f_A, double rs_ohm, double ld_H,
                                                   double omega_e_rad_s);

// ---- Signal resolution (Section VI-A) ----

struct ResolvedSignal {
  double vr_V = 0.0;  // resistive component, along theta_r
  double vl_V = 0.0;  // inductive component, along theta_l
};

// Eq. 22: resolves a stator-frame voltage of magnitude Vqds at angle theta_qds into components
// along the resistive (theta_r) and inductive (theta_l) directions, which need not be
// orthogonal. Returns nothing useful when theta_r and theta_l are parallel (the caller must
// check resolvable() first).
[[nodiscard]] ResolvedSignal resolve_signal_voltage(double vqds_V, double theta_qds_rad,
                                                    double theta_r_rad, double theta_l_rad);

// |sin(theta_r - theta_l)|: how well Eq. 22 is conditioned (0 = unresolvable).
[[nodiscard]] double resolution_conditioning(double theta_r_rad, double theta_l_rad);

// The stator-frame directions of the resistive and inductive voltages of fixed-angle
// injection at rotor angle theta (from Eqs. 14-15): theta_r = theta (the d-axis, signed by
// cos(thF - th)), theta_l = theta + pi/2 - (thF - th) (the direction of (sin, cos) in dq).
struct SignalDirections {
  double theta_r_rad = 0.0;
  double theta_l_rad = 0.0;
};
[[nodiscard]] SignalDirections fixed_angle_signal_directions(double theta_f_rad, double theta_rad);

// ---- Budget and losses (Sections VII-VIII) ----

// Eq. 29: voltage needed to inject F through a window of period Tw,
// Vinj = F sqrt((k Ld / Tw)^2 + Rs^2), k = max |dB/dt| Tw (1.81 for B, 2.04 for B2).
[[nodiscard]] double required_injection_voltage_V(double f_A, double ld_H, double rs_ohm,
                                                  double tw_s, WindowKind kind);

// The default window period: the paper's 4 ms, or longer where an edge of F through Ld would
// take more than half the phase voltage limit by Eq. 29's inductive term (k Ld F / Tw). Table I
// (5.5 mH, the calibration's 50 A, 650 V) asks 37 % of it at 4 ms; a 0.1 H ball-mill motor's
// 10 A asked 561 V of 323 (docs/estimator.md section 2, "The window's period"). At most
// kMaxWindowPeriod_s.
[[nodiscard]] double default_window_period_s(double f_A, double ld_H, double phase_voltage_limit_V, WindowKind kind);

// Eq. 29 inverted: the largest F for a given voltage headroom (the curves of Fig. 8).
[[nodiscard]] double max_injection_current_A(double headroom_V, double ld_H, double rs_ohm,
                                             double tw_s, WindowKind kind);

// Headroom at an operating point. Eq. 29 sizes the voltage a window edge needs on its own;
// in a running machine the motoring voltage (Eq. 3) already uses part of the circle, and
// fixed-magnitude injection adds w Ld F on the q-axis (Eq. 21). This finds the largest F for
// which the worst case of the two stays inside the voltage limit:
//   vd = vd0 + s F sqrt((k Ld / Tw)^2 + Rs^2),   vq = vq0 + s w Ld F,   s = polarity (+1/-1),
// with (vd0, vq0) the steady-state motoring voltage of Eq. 3. Conservative: the window's
// steepest slope and the full q-axis term are taken at the same instant.
struct InjectionHeadroomInput {
  double rs_ohm = 0.133;
  double ld_H = 5.5e-3;
  double lq_H = 5.5e-3;
  double flux_linkage_Wb = 0.3239;
  double omega_e_rad_s = 0.0;
  double id_A = 0.0;              // motoring current before injection
  double iq_A = 0.0;
  double voltage_limit_V = 356.0; // usable voltage, e.g. 0.95 Vdc / sqrt(3)
  double tw_s = 0.01;
  WindowKind window = WindowKind::kBlackman;
  // Added to Eq. 3's motoring voltage: what the machine needs beyond the model at this operating
  // point (the current loop's command less the model's, InjectionScheduler::budget). Zero: the
  // model alone.
  Dq motoring_voltage_error_V{};
};

// Steady-state motoring voltage (Eq. 3 with d/dt = 0), plus motoring_voltage_error_V.
[[nodiscard]] Dq motoring_voltage(const InjectionHeadroomInput& in);

// Largest F >= 0 for one polarity (+1 or -1); 0 when the motoring voltage alone is at or
// beyond the limit.
[[nodiscard]] double max_injection_current_at_operating_point_A(const InjectionHeadroomInput& in,
                                                                double polarity);

// The largest d-axis injection F whose reluctance torque, 1.5 p |Ld - Lq| F |iq|, stays within
// a budget (injection.max_torque_disturbance_Nm): budget / (1.5 p |Ld - Lq| |iq|). +infinity
// where nothing limits it (no budget, Ld = Lq or no load).
[[nodiscard]] double max_injection_current_for_torque_A(double budget_Nm, int pole_pairs, double ld_H, double lq_H,
                                                        double iq_A);

// The largest injection F of one polarity (+1 or -1) whose sum with the motoring current
// (id, iq) stays within the current limit (peak A). A fixed-magnitude d-axis pulse:
// |(id + polarity F, iq)| <= limit, i.e. sqrt(limit^2 - iq^2) - polarity id. A vector turning
// relative to the rotor (fixed-angle, DC: turning_vector) points every way in turn: F <= limit -
// |(id, iq)|. 0 where the motoring current alone reaches the limit (never negative).
[[nodiscard]] double max_injection_current_for_current_limit_A(double limit_A, double id_A, double iq_A,
                                                               double polarity, bool turning_vector = false);

// The range of F >= 0 for one polarity inside which the same worst case stays within the
// limit. At the voltage limit (|v0| at or beyond it) a polarity that weakens the field
// (s = -1 at speed: w Ld F lowers vq) still has a range [lo, hi] with lo > 0: the level an
// injection must reach to come off the limit, and the level at which it would hit it again.
// Empty (valid = false) when no F fits.
struct InjectionCurrentRange {
  bool valid = false;
  double lo_A = 0.0;
  double hi_A = 0.0;
};
[[nodiscard]] InjectionCurrentRange injection_current_range_at_operating_point_A(
    const InjectionHeadroomInput& in, double polarity);

// Eq. 30: per-phase current requirement Iinj = 2/3 F.
[[nodiscard]] double per_phase_injection_current_A(double f_A);

struct InjectionSchedule {
  double f_A = 25.0;           // injection magnitude
  double rs_ohm = 0.133;
  int pulses = 3;              // Ninj, pulses in the elapsed time
  double elapsed_s = 10.0;     // Tel
  double ti_s = 0.2;           // flat-top duration of one pulse
  double tw_s = 0.01;          // window period
  WindowKind window = WindowKind::kBlackman;
};

// Eq. 32: average loss of fixed-magnitude injection, P = F^2 Ninj Rs / Tel (Ti + c Tw), with
// c = integral of the window (0.84 or 1.25, Eqs. 27-28), as the paper writes it.
[[nodiscard]] double fixed_magnitude_average_loss_W(const InjectionSchedule& s);

// Eq. 31: average loss of fixed-angle injection,
// P = F^2 Ninj Rs / Tel (2/w sin(w Ti / 2) + c Tw), as the paper writes it.
[[nodiscard]] double fixed_angle_average_loss_W(const InjectionSchedule& s, double omega_e_rad_s);

// The dissipated energy computed exactly (integral of i^2 rather than of i, which Eqs. 31-32
// use), for comparison: fixed magnitude  P = 3/2 F^2 Rs Ninj / Tel (Ti + c2 Tw), with
// c2 = integral of B^2 / Tw, and the 3/2 of amplitude-invariant dq power.
[[nodiscard]] double fixed_magnitude_average_loss_exact_W(const InjectionSchedule& s);

// Eq. 31's counterpart for fixed-angle injection, computed by integrating the envelope and
// cos^2 numerically, including the 3/2 factor.
[[nodiscard]] double fixed_angle_average_loss_exact_W(const InjectionSchedule& s,
                                                      double omega_e_rad_s);

}  // namespace pmsm::core
