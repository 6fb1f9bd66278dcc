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

Abc dead_time_compensation_V(const Abc& i_A, const DeadTimeCompensation& comp, double vdc_V,
                             double period_s) {
  // The bridge loses dead_time/period of the bus voltage, plus the device drop, against the
  // current in each phase.
  const double error_V = comp.dead_time_s / period_s * vdc_V + comp.device_drop_V;
  return {error_V * soft_sign(i_A.a, comp.current_band_A), error_V * soft_sign(i_A.b, comp.current_band_A),
          error_V * soft_sign(i_A.c, comp.current_band_A)};
}

Duties svpwm_compensated(const AlphaBeta& v_V, double vdc_V, const Abc& i_A,
                         const DeadTimeCompensation& comp, double period_s) {
  // Add the expected loss back before the common mode is chosen.
  const Abc v = inverse_clarke(v_V);
  const Abc e = dead_time_compensation_V(i_A, comp, vdc_V, period_s);
  return duties_from_phase_voltages({v.a + e.a, v.b + e.b, v.c + e.c}, vdc_V);
}

}  // namespace pmsm::core
