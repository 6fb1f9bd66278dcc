#include "pmsm/core/modulation.hpp"

#include <algorithm>

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

}  // namespace

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
