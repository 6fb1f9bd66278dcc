#include "pmsm/core/modulation.hpp"

#include <algorithm>

namespace pmsm::core {
namespace {

Duties duties_from_phase_voltages(const std::array<double, 3>& v, double vdc_V) {
  const auto [lo, hi] = std::minmax({v[0], v[1], v[2]});
  const double common_mode = -0.5 * (lo + hi);
  Duties out;
  for (std::size_t n = 0; n < 3; ++n) {
    const double duty = 0.5 + (v[n] + common_mode) / vdc_V;
    out.value[n] = std::clamp(duty, 0.0, 1.0);
    out.clipped = out.clipped || out.value[n] != duty;
  }
  return out;
}

}  // namespace

double soft_sign(double i_A, double current_band_A) {
  if (current_band_A <= 0.0) {
    return i_A > 0.0 ? 1.0 : (i_A < 0.0 ? -1.0 : 0.0);
  }
  return std::clamp(i_A / current_band_A, -1.0, 1.0);
}

Duties svpwm(const AlphaBeta& v_V, double vdc_V) {
  const Abc v = inverse_clarke(v_V);
  return duties_from_phase_voltages({v.a, v.b, v.c}, vdc_V);
}

double mean_soft_sign(double i0_A, double i1_A, double current_band_A) {
  // Antiderivative of soft_sign: x^2 / 2b inside the band, |x| - b/2 outside (|x| for b = 0).
  const double b = std::max(current_band_A, 0.0);
  auto antiderivative = [b](double x) {
    const double m = std::abs(x);
    return m <= b && b > 0.0 ? x * x / (2.0 * b) : m - 0.5 * b;
  };
  const double span = i1_A - i0_A;
  if (std::abs(span) < 1e-9) {
    return soft_sign(0.5 * (i0_A + i1_A), b);
  }
  return (antiderivative(i1_A) - antiderivative(i0_A)) / span;
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
