// Space-vector PWM (as min-max zero-sequence injection, which gives the same switching
// pattern as classical SVPWM) and dead-time compensation.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>

#include "pmsm/core/transforms.hpp"

namespace pmsm::core {

struct DeadTimeCompensation {
  double dead_time_s = 0.0;       // the dead time the controller believes the bridge has
  double device_drop_V = 0.0;     // the forward drop it believes the devices have
  double current_band_A = 1.0;    // below this |i| the correction fades in linearly
};

struct Duties {
  std::array<double, 3> value{0.5, 0.5, 0.5};  // high-side duty per phase, 0..1
  bool clipped = false;                        // some phase hit 0 or 1
};

// Duty cycles that make the average phase-to-neutral voltage equal to inverse_clarke(v) on a
// bus of vdc, with the common mode centred (SVPWM).
[[nodiscard]] Duties svpwm(const AlphaBeta& v_V, double vdc_V);

// As svpwm(), plus a correction per phase that cancels the expected dead-time and device-drop
// error for the phase currents expected at the start (i0) and end (i1) of the period (the
// error opposes the current).
[[nodiscard]] Duties svpwm_compensated(const AlphaBeta& v_V, double vdc_V, const Abc& i0_A, const Abc& i1_A,
                                       const DeadTimeCompensation& comp, double period_s);

// As svpwm(), plus a given correction per phase (e.g. dead_time_compensation_V(), computed
// once by a caller that also needs it) added before the common mode is chosen.
[[nodiscard]] Duties svpwm_corrected(const AlphaBeta& v_V, double vdc_V, const Abc& correction_V);

// The bridge's voltage error per phase the compensation cancels for a current well outside
// its band: the dead time's share of the bus, plus the device drop.
[[nodiscard]] inline double dead_time_error_V(const DeadTimeCompensation& comp, double vdc_V, double period_s) {
  return comp.dead_time_s / period_s * vdc_V + comp.device_drop_V;
}

// Whether the bridge may not apply these duties as commanded although none clipped: a duty
// closer to a rail than kPulseDeadTimeMargin (1.5) times the dead time's fraction of the period,
// on the side where the phase's current takes the dead time from its pulse (the plant: clamp(duty
// - fraction sgn(i), 0, 1): a positive current at the low rail, a negative one at the high).
// The current's sign is the compensation's (`correction_V` over `error_V`, dead_time_error_V:
// +-1 outside its band, in between near a zero crossing, where either sign counts); the margin
// is for a dead time the drive underestimates (the scenarios commission it 5-33 % low). Centred
// duties lie (1 - spread / vdc) / 2 from the rails, and the spread is at most sqrt(3) |v| plus
// twice the largest correction e: on a voltage limit of a fraction f of Vdc / sqrt(3), only a
// bus with Vdc (1 - f - 2 (1 + kPulseDeadTimeMargin) fraction) < 2 drop can meet it (the
// reference's 0.9 us at 10 kHz and no drop: none). The drive asks only there
// (DriveController::step), and a pair whose recording holds such a period is rejected
// (PeriodSample::modulation_clipped).
inline constexpr double kPulseDeadTimeMargin = 1.5;
[[nodiscard]] bool pulse_lost(const Duties& duties, const Abc& correction_V, double error_V, double dead_time_fraction);

// The phase-voltage error per phase the compensation assumes, as a fraction of one unit of
// "sign(i)": a linear ramp through zero inside +-current_band and +-1 outside.
// Inline, as mean_soft_sign: the control step calls them six times a period.
[[nodiscard]] inline double soft_sign(double i_A, double current_band_A) {
  if (current_band_A <= 0.0) {
    return i_A > 0.0 ? 1.0 : (i_A < 0.0 ? -1.0 : 0.0);
  }
  return std::clamp(i_A / current_band_A, -1.0, 1.0);
}

// The mean of soft_sign over a period in which the current moves linearly from i0 to i1: a
// zero crossing inside the period then counts for the fraction of the period spent on
// each side, as it does in the bridge (at speed the current moves about an ampere per period).
// Antiderivative of soft_sign for a band b >= 0: x^2 / 2b inside the band, |x| - b/2 outside
// (|x| for b = 0).
[[nodiscard]] inline double soft_sign_antiderivative(double x, double b) {
  const double m = std::abs(x);
  return m <= b && b > 0.0 ? x * x / (2.0 * b) : m - 0.5 * b;
}

[[nodiscard]] inline double mean_soft_sign(double i0_A, double i1_A, double current_band_A) {
  const double b = std::max(current_band_A, 0.0);
  // Outside the band on one side throughout, as most phases are in most periods: the sign is
  // constant, exactly (the quotient below loses about ulp(i) / span to cancellation, at the
  // cost of a division). Infinite currents on one side give the sign too; the drive's
  // measured currents are finite (DriveController::controllable).
  if (i0_A > b && i1_A > b) {
    return 1.0;
  }
  if (i0_A < -b && i1_A < -b) {
    return -1.0;
  }
  const double span = i1_A - i0_A;
  if (std::abs(span) < 1e-9) {
    return soft_sign(0.5 * (i0_A + i1_A), b);
  }
  return (soft_sign_antiderivative(i1_A, b) - soft_sign_antiderivative(i0_A, b)) / span;
}

// mean_soft_sign of two *measured* currents, corrected for their noise. The bridge's error
// follows the true current; a sample's noise (standard deviation sigma) smooths the knees of
// the ramp at +-b, so the plain mean reads the sign pattern's magnitude low wherever a phase
// passes a knee (Gaussian smoothing: E[f(x + n)] = f(x) + sigma^2/2 f''(x) to first order, and
// f'' = (delta(x + b) - delta(x - b)) / b). The correction adds back sigma_eff^2 / (2 b) times the
// period's mean normal density at the two knees along the sampled line, with sigma_eff^2 =
// 2/3 sigma^2: the noise of a point on the line between two samples is their noises' blend,
// whose variance averages 2/3 of one sample's over the period. Checked by Monte Carlo
// (core_modulation_test): the pattern's bias near the knees falls to 2-20 % of the
// uncorrected one. Measured in closed loop: field-weakening pairs at 314 rad/s and 5 Nm read
// -1.96 % uncorrected, -1.29 % corrected, -1.11 % with noiseless current sensors
// (docs/estimator.md section 4). Costs nothing unless the line passes within 4.5 sigma_eff
// of a knee, and a normal CDF from a table only for a sample that close to it (each density is 0
// beyond, off by 3.4e-6 at most). The correction itself is out of line (modulation.cpp), so that the common
// case below stays a few compares inline.
[[nodiscard]] double soft_sign_noise_correction(double i0_A, double i1_A, double current_band_A, double sigma_eff_A);
// How far from a knee, in sigma_eff, the correction reaches (each density is 0 beyond).
inline constexpr double kNoiseCorrectionReachSigma = 4.5;

[[nodiscard]] inline double mean_soft_sign_of_measured(double i0_A, double i1_A, double current_band_A,
                                                       double sigma_eff_A) {
  if (sigma_eff_A > 0.0 && current_band_A > 0.0) {
    // Only a line that comes within 4.5 sigma_eff of a knee: [lo, hi] meets
    // [-b - r, b + r] and does not stay inside (-b + r, b - r).
    const double lo = std::min(i0_A, i1_A);
    const double hi = std::max(i0_A, i1_A);
    const double r = kNoiseCorrectionReachSigma * sigma_eff_A;
    const double b = current_band_A;
    if (lo < b + r && hi > -b - r && !(lo > r - b && hi < b - r)) {
      return mean_soft_sign(i0_A, i1_A, b) + soft_sign_noise_correction(i0_A, i1_A, b, sigma_eff_A);
    }
  }
  return mean_soft_sign(i0_A, i1_A, current_band_A);
}

// Whether soft_sign can change over a period in which the current moves from i0 to i1, for a
// band b >= 0: the current enters the band (b = 0: crosses zero). Otherwise its sign is constant.
[[nodiscard]] inline bool soft_sign_varies(double i0_A, double i1_A, double b) {
  return (i0_A < b || i1_A < b) && (i0_A > -b || i1_A > -b);
}

// The first moment of soft_sign over the same period, in units of the period: the integral
// of u soft_sign(i(u)) du for u in [-1/2, 1/2] and i(u) = (i0 + i1) / 2 + (i1 - i0) u. Zero
// while the current stays on one side outside the band (the sign is constant there). The
// period's mean current needs it: a sign that flips inside the period bends the current
// (DriveController::step, "the period's mean current").
[[nodiscard]] inline double soft_sign_moment(double i0_A, double i1_A, double current_band_A) {
  const double b = std::max(current_band_A, 0.0);
  if (!soft_sign_varies(i0_A, i1_A, b)) {
    return 0.0;  // outside the band throughout (b = 0: no crossing): the sign is constant
  }
  const double span = i1_A - i0_A;
  if (std::abs(span) < 1e-6 * std::max(b, 1e-3)) {
    return b > 0.0 ? span / (12.0 * b) : 0.0;  // inside the band, where soft_sign is linear
  }
  // (H(i1) - H(i0) - mid (F(i1) - F(i0))) / span^2, with F the antiderivative of soft_sign
  // and H that of x soft_sign(x): x^3 / 3b inside the band, x |x| / 2 - sign(x) b^2 / 6
  // outside (continuous at +-b).
  auto h = [b](double x) {
    const double m = std::abs(x);
    return m <= b && b > 0.0 ? x * x * x / (3.0 * b) : 0.5 * x * m - std::copysign(b * b / 6.0, x);
  };
  const double mid = 0.5 * (i0_A + i1_A);
  return (h(i1_A) - h(i0_A) - mid * (soft_sign_antiderivative(i1_A, b) - soft_sign_antiderivative(i0_A, b))) /
         (span * span);
}

// The voltage per phase that svpwm_compensated() adds, for currents moving from i0 to i1
// over the period the command applies to.
[[nodiscard]] Abc dead_time_compensation_V(const Abc& i0_A, const Abc& i1_A, const DeadTimeCompensation& comp,
                                           double vdc_V, double period_s);

}  // namespace pmsm::core
