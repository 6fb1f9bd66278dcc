#include "pmsm/plant/emf.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace pmsm::plant {
namespace {

// A built-in shape: a spectral pattern (relative weights) scaled so that the fundamental is
// exactly `fraction` of the waveform's peak. The signs make every harmonic peak together
// with the fundamental at theta = 90° (sin(n·90°) = +1 for n = 1 mod 4, -1 for n = 3 mod 4),
// so the peak of |f| is 1 + sum|b_n| and the fraction is 1 / (1 + sum|b_n|) exactly.
template <std::size_t N>
constexpr std::array<EmfHarmonic, N> scaled_spectrum(const std::array<int, N>& orders,
                                                     const std::array<double, N>& weights,
                                                     double fraction) {
  double weight_sum = 0.0;
  for (double w : weights) {
    weight_sum += w;
  }
  const double scale = (1.0 / fraction - 1.0) / weight_sum;
  std::array<EmfHarmonic, N> out{};
  for (std::size_t i = 0; i < N; ++i) {
    const double sign = (orders[i] % 4 == 1) ? 1.0 : -1.0;
    out[i] = EmfHarmonic{orders[i], sign * weights[i] * scale};
  }
  return out;
}

// "Modular" (fractional-slot, concentrated-winding) machine: a broad spectrum falling as
// 1/n, 89 % fundamental (Fig. 11).
constexpr auto kModular = scaled_spectrum<4>({5, 7, 11, 13},
                                             {1.0 / 5.0, 1.0 / 7.0, 1.0 / 11.0, 1.0 / 13.0},
                                             0.89);

// "Trapezoidal" machine: the non-triplen part of the spectrum of a trapezoid with 30° ramps
// (amplitudes falling as 1/n²), scaled to 77 % fundamental (Fig. 11). With the triplens
// removed by the isolated neutral the phase EMF is peaked rather than flat-topped.
constexpr auto kTrapezoidal = scaled_spectrum<6>(
    {5, 7, 11, 13, 17, 19},
    {1.0 / 25.0, 1.0 / 49.0, 1.0 / 121.0, 1.0 / 169.0, 1.0 / 289.0, 1.0 / 361.0}, 0.77);

}  // namespace

std::span<const EmfHarmonic> builtin_emf_harmonics(EmfShape shape) {
  switch (shape) {
    case EmfShape::modular:
      return kModular;
    case EmfShape::trapezoidal:
      return kTrapezoidal;
    case EmfShape::sinusoidal:
    case EmfShape::custom:
      break;
  }
  return {};
}

EmfModel::EmfModel(const EmfConfig& config) {
  std::span<const EmfHarmonic> source = builtin_emf_harmonics(config.shape);
  std::array<EmfHarmonic, kMaxEmfHarmonics> custom{};
  if (config.shape == EmfShape::custom) {
    const std::size_t n = std::min({config.custom_orders.size(),
                                    config.custom_amplitudes.size(), kMaxEmfHarmonics});
    for (std::size_t i = 0; i < n; ++i) {
      custom[i] = EmfHarmonic{config.custom_orders[i], config.custom_amplitudes[i]};
    }
    source = std::span<const EmfHarmonic>(custom.data(), n);
  }
  for (const EmfHarmonic& h : source) {
    // validate_plant_config() rejects even and triplen orders; skip them defensively so
    // that a hand-built config cannot inject a zero-sequence term.
    if (h.order < 5 || h.order > kMaxEmfOrder || h.order % 2 == 0 || h.order % 3 == 0 ||
        count_ >= kMaxEmfHarmonics) {
      continue;
    }
    harmonics_[count_] = h;
    // n = 6k+1 is a positive-sequence set, n = 6k-1 a negative-sequence set; both appear
    // at 6k·theta in the rotor frame.
    const auto k = static_cast<std::size_t>((h.order + 1) / 6);
    terms_[count_] = RotorTerm{h.amplitude, (h.order % 6 == 1) ? h.amplitude : -h.amplitude, k};
    max_six_multiple_ = std::max(max_six_multiple_, k);
    peak_bound_ += std::abs(h.amplitude);
    ++count_;
  }
}

double EmfModel::phase_shape(double theta_e_rad) const {
  double f = -std::sin(theta_e_rad);
  for (std::size_t i = 0; i < count_; ++i) {
    f -= harmonics_[i].amplitude * std::sin(harmonics_[i].order * theta_e_rad);
  }
  return f;
}

void EmfModel::dq_shape(double theta_e_rad, double& g_d, double& g_q) const {
  dq_shape(std::cos(theta_e_rad), std::sin(theta_e_rad), g_d, g_q);
}

void EmfModel::dq_shape(double cos_theta, double sin_theta, double& g_d, double& g_q) const {
  g_d = 0.0;
  g_q = 1.0;
  if (count_ == 0) {
    return;
  }
  // e^{j6θ} = ((e^{jθ})³)² by complex multiplication: no trigonometric call per harmonic,
  // rounding errors of order 1e-15.
  const double c2 = cos_theta * cos_theta - sin_theta * sin_theta;
  const double s2 = 2.0 * cos_theta * sin_theta;
  const double c3 = c2 * cos_theta - s2 * sin_theta;
  const double s3 = s2 * cos_theta + c2 * sin_theta;
  const double c6 = c3 * c3 - s3 * s3;
  const double s6 = 2.0 * c3 * s3;
  // Then e^{j6kθ} by repeated multiplication. Only the first max_six_multiple_ + 1 entries
  // are written and read; skipping the zero-initialisation of the rest matters in this hot path.
  std::array<double, kMaxEmfSixMultiple + 1> ck;  // NOLINT(cppcoreguidelines-pro-type-member-init)
  std::array<double, kMaxEmfSixMultiple + 1> sk;  // NOLINT(cppcoreguidelines-pro-type-member-init)
  ck[0] = 1.0;
  sk[0] = 0.0;
  for (std::size_t k = 1; k <= max_six_multiple_; ++k) {
    ck[k] = ck[k - 1] * c6 - sk[k - 1] * s6;
    sk[k] = sk[k - 1] * c6 + ck[k - 1] * s6;
  }
  // Local sums: g_d and g_q could alias this object, and storing them through their
  // references every term cost a third of the function.
  double d = 0.0;
  double q = 1.0;
  for (std::size_t i = 0; i < count_; ++i) {
    const RotorTerm& term = terms_[i];
    d -= term.d_weight * sk[term.six_multiple];
    q += term.q_weight * ck[term.six_multiple];
  }
  g_d = d;
  g_q = q;
}

double EmfModel::fundamental_fraction() const {
  // Dense sampling of one electrical period; the peak of a spectrum up to order 19 is
  // resolved to far better than 1e-5 with 20000 points.
  constexpr int kPoints = 20000;
  double peak = 0.0;
  for (int i = 0; i < kPoints; ++i) {
    const double theta = 2.0 * std::numbers::pi * static_cast<double>(i) / kPoints;
    peak = std::max(peak, std::abs(phase_shape(theta)));
  }
  return 1.0 / peak;
}

}  // namespace pmsm::plant
