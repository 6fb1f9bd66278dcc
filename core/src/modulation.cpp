#include "pmsm/core/modulation.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>

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

// The standard normal CDF on [-4.5, 4.5] by cubic Hermite interpolation between nodes 1/16
// apart, from the CDF and its derivative (the density) at each node: within 2.2e-8 of erfc
// (max |Phi''''| h^4 / 384, max |Phi''''| = 0.55), its first derivative within 1.1e-6 of the density,
// for the price of a few multiplications where erfc costs about a hundred instructions and a
// loaded phase passes the band's knees in many periods (docs/performance.md). Beyond 4.5
// standard deviations 0 or 1 (off by 3.4e-6 at most; at +-4.5 exactly the node's value, as
// erfc's was). Built once, at static initialisation: nothing may call it from another static
// object's constructor (none does; the controllers are built in main).
class NormalCdfTable {
 public:
  NormalCdfTable() {
    constexpr double kInvSqrt2 = 0.70710678118654752440;
    constexpr double kInvSqrt2Pi = 0.39894228040143267794;
    for (std::size_t k = 0; k < kNodes; ++k) {
      const double z = -kRange + static_cast<double>(k) / kPerUnit;
      cdf_[k] = 0.5 * std::erfc(-z * kInvSqrt2);
      pdf_[k] = kInvSqrt2Pi * std::exp(-0.5 * z * z) / kPerUnit;  // d/du of the node interval's unit
    }
  }

  [[nodiscard]] double operator()(double z) const {
    if (!(z >= -kRange)) {
      return z < -kRange ? 0.0 : z;  // NaN stays NaN
    }
    if (z > kRange) {
      return 1.0;
    }
    const double t = (z + kRange) * kPerUnit;
    const auto k = std::min(static_cast<std::size_t>(t), kNodes - 2);
    const double u = t - static_cast<double>(k);
    const double v = 1.0 - u;
    // Hermite basis: (1 + 2u) v^2, u v^2, u^2 (3 - 2u), -u^2 v.
    return (1.0 + 2.0 * u) * v * v * cdf_[k] + u * v * v * pdf_[k] + u * u * (3.0 - 2.0 * u) * cdf_[k + 1] -
           u * u * v * pdf_[k + 1];
  }

 private:
  static constexpr double kRange = 4.5;
  static constexpr double kPerUnit = 16.0;
  static constexpr auto kNodes = static_cast<std::size_t>(2.0 * kRange * kPerUnit) + 1;  // 145
  std::array<double, kNodes> cdf_{};
  std::array<double, kNodes> pdf_{};
};

const NormalCdfTable kNormalCdf;

double normal_cdf_clamped(double z) { return kNormalCdf(z); }

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
  const double error_V = dead_time_error_V(comp, vdc_V, period_s);
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

bool pulse_lost(const Duties& duties, const Abc& correction_V, double error_V, double dead_time_fraction) {
  const double edge = kPulseDeadTimeMargin * std::abs(dead_time_fraction);
  const std::array<double, 3> correction{correction_V.a, correction_V.b, correction_V.c};
  const double e = std::abs(error_V);
  for (std::size_t n = 0; n < 3; ++n) {
    // The current's sign as the compensation has it: surely negative, surely positive, or either.
    const bool may_be_positive = !(correction[n] <= -e);
    const bool may_be_negative = !(correction[n] >= e);
    if ((may_be_positive && !(duties.value[n] >= edge)) || (may_be_negative && !(duties.value[n] <= 1.0 - edge))) {
      return true;
    }
  }
  return false;
}

}  // namespace pmsm::core
