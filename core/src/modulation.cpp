#include "pmsm/core/modulation.hpp"

#include <algorithm>
#include <cmath>

namespace pmsm::core {
namespace {

Duties duties_from_phase_voltages(const std::array<double, 3>& v, double vdc_V) {
  const double lo = std::min(std::min(v[0], v[1]), v[2]);
  const double hi = std::max(std::max(v[0], v[1]), v[2]);
  const double common_mode = -0.5 * (lo + hi);
  Duties out;
  for (std::size_t n = 0; n < 3; ++n) {
    const double duty = 0.5 + (v[n] + common_mode) / vdc_V;
    out.value[n] = std::clamp(duty, 0.0, 1.0);
    out.clipped = out.clipped || out.value[n] != duty;
  }
  return out;
}

// The standard normal CDF; beyond 4.5 standard deviations 0 or 1 (off by 3.4e-6 at most), so
// that only samples near a knee cost an erfc.
double normal_cdf_clamped(double z) {
  constexpr double kInvSqrt2 = 0.70710678118654752440;
  if (z < -4.5) {
    return 0.0;
  }
  if (z > 4.5) {
    return 1.0;
  }
  return 0.5 * std::erfc(-z * kInvSqrt2);
}

// The mean over u in [0, 1] of the normal density (sigma) at i0 + (i1 - i0) u - x.
double normal_mean_along(double i0_A, double i1_A, double x_A, double sigma_A) {
  constexpr double kInvSqrt2Pi = 0.39894228040143267794;
  const double span = i1_A - i0_A;
  const double z0 = (i0_A - x_A) / sigma_A;
  if (std::abs(span) < 1e-3 * sigma_A) {
    return std::abs(z0) > 9.0 ? 0.0 : kInvSqrt2Pi / sigma_A * std::exp(-0.5 * z0 * z0);
  }
  const double z1 = (i1_A - x_A) / sigma_A;
  return (normal_cdf_clamped(z1) - normal_cdf_clamped(z0)) / span;
}

}  // namespace

double soft_sign_noise_correction(double i0_A, double i1_A, double current_band_A, double sigma_eff_A) {
  const double b = current_band_A;
  const double upper = normal_mean_along(i0_A, i1_A, b, sigma_eff_A);
  const double lower = normal_mean_along(i0_A, i1_A, -b, sigma_eff_A);
  return sigma_eff_A * sigma_eff_A / (2.0 * b) * (upper - lower);
}

Duties svpwm(const AlphaBeta& v_V, double vdc_V) {
  const Abc v = inverse_clarke(v_V);
  return duties_from_phase_voltages({v.a, v.b, v.c}, vdc_V);
}

Abc dead_time_compensation_V(const Abc& i0_A, const Abc& i1_A, const DeadTimeCompensation& comp,
                             double vdc_V, double period_s) {
  // The bridge loses dead_time/period of the bus voltage, plus the device drop, against the
  // current in each phase.
  const double error_V = comp.dead_time_s / period_s * vdc_V + comp.device_drop_V;
  const double b = comp.current_band_A;
  return {error_V * mean_soft_sign(i0_A.a, i1_A.a, b), error_V * mean_soft_sign(i0_A.b, i1_A.b, b),
          error_V * mean_soft_sign(i0_A.c, i1_A.c, b)};
}

Duties svpwm_compensated(const AlphaBeta& v_V, double vdc_V, const Abc& i0_A, const Abc& i1_A,
                         const DeadTimeCompensation& comp, double period_s) {
  // Add the expected loss back before the common mode is chosen.
  return svpwm_corrected(v_V, vdc_V, dead_time_compensation_V(i0_A, i1_A, comp, vdc_V, period_s));
}

Duties svpwm_corrected(const AlphaBeta& v_V, double vdc_V, const Abc& correction_V) {
  const Abc v = inverse_clarke(v_V);
  return duties_from_phase_voltages({v.a + correction_V.a, v.b + correction_V.b, v.c + correction_V.c}, vdc_V);
}

}  // namespace pmsm::core
