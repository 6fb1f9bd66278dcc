#include "pmsm/core/window.hpp"

#include <array>
#include <cmath>

#include "pmsm/core/transforms.hpp"

namespace pmsm::core {
namespace {

struct Coefficients {
  double a0;
  double a1;
  double a2;
};

// B  = 0.42  + 0.5 cos(pi tn / Tw) + 0.08  cos(2 pi tn / Tw)   (Eq. 23)
// B2 = 0.625 + 0.5 cos(pi tn / Tw) - 0.125 cos(2 pi tn / Tw)   (Eq. 24)
constexpr Coefficients coefficients(WindowKind kind) {
  return kind == WindowKind::kBlackman ? Coefficients{0.42, 0.5, 0.08}
                                       : Coefficients{0.625, 0.5, -0.125};
}

double normalised_slope(WindowKind kind, double x) {
  // |dB/dt| * Tw as a function of x = tn / Tw.
  const Coefficients c = coefficients(kind);
  return std::abs(-c.a1 * kPi * std::sin(kPi * x) - 2.0 * c.a2 * kPi * std::sin(2.0 * kPi * x));
}

}  // namespace

std::string_view to_string(WindowKind kind) {
  return kind == WindowKind::kBlackman ? "blackman" : "modified";
}

double window_value(WindowKind kind, double tn_s, double tw_s) {
  if (std::abs(tn_s) > tw_s) {
    return 0.0;
  }
  const Coefficients c = coefficients(kind);
  // cos 2x from cos x: one fixed-cost rotation instead of two libm cosines per period.
  const double cos_x = rotation(kPi * tn_s / tw_s).c;
  return c.a0 + c.a1 * cos_x + c.a2 * (2.0 * cos_x * cos_x - 1.0);
}

double window_derivative_per_s(WindowKind kind, double tn_s, double tw_s) {
  if (std::abs(tn_s) > tw_s) {
    return 0.0;
  }
  const Coefficients c = coefficients(kind);
  const Rotation r = rotation(kPi * tn_s / tw_s);
  return (-c.a1 * r.s - 2.0 * c.a2 * (2.0 * r.s * r.c)) * kPi / tw_s;
}

WindowConstants compute_window_constants(WindowKind kind) {
  WindowConstants out;

  // Maximum slope: coarse scan of x = tn/Tw over [-1, 1], then golden-section refinement
  // around the best sample.
  constexpr int kScan = 2000;
  int best = 0;
  double best_value = 0.0;
  for (int n = 0; n <= kScan; ++n) {
    const double x = -1.0 + 2.0 * n / kScan;
    const double v = normalised_slope(kind, x);
    if (v > best_value) {
      best_value = v;
      best = n;
    }
  }
  double lo = -1.0 + 2.0 * (best - 1) / kScan;
  double hi = -1.0 + 2.0 * (best + 1) / kScan;
  constexpr double kGolden = 0.61803398874989485;
  for (int iteration = 0; iteration < 100; ++iteration) {
    const double x1 = hi - kGolden * (hi - lo);
    const double x2 = lo + kGolden * (hi - lo);
    if (normalised_slope(kind, x1) > normalised_slope(kind, x2)) {
      hi = x2;
    } else {
      lo = x1;
    }
  }
  out.max_slope_times_tw = normalised_slope(kind, 0.5 * (lo + hi));

  // Integrals over [-Tw, Tw] with Tw = 1 by composite Simpson's rule.
  constexpr int kIntervals = 4000;  // even
  constexpr double h = 2.0 / kIntervals;
  double sum = 0.0;
  double sum_squared = 0.0;
  for (int n = 0; n <= kIntervals; ++n) {
    const double weight = (n == 0 || n == kIntervals) ? 1.0 : (n % 2 == 1 ? 4.0 : 2.0);
    const double v = window_value(kind, -1.0 + n * h, 1.0);
    sum += weight * v;
    sum_squared += weight * v * v;
  }
  out.integral_per_tw = sum * h / 3.0;
  out.integral_squared_per_tw = sum_squared * h / 3.0;
  return out;
}

const WindowConstants& window_constants(WindowKind kind) {
  static const std::array<WindowConstants, 2> table{compute_window_constants(WindowKind::kBlackman),
                                                    compute_window_constants(WindowKind::kModifiedBlackman)};
  return table[kind == WindowKind::kBlackman ? 0 : 1];
}

double PulseEnvelope::value(double t_s) const {
  if (t_s <= 0.0 || t_s >= duration_s()) {
    return 0.0;
  }
  if (t_s < tw_s) {
    return window_value(kind, t_s - tw_s, tw_s);  // rising half, tn from -Tw to 0
  }
  if (t_s <= tw_s + ti_s) {
    return 1.0;
  }
  return window_value(kind, t_s - tw_s - ti_s, tw_s);  // falling half, tn from 0 to Tw
}

double PulseEnvelope::derivative_per_s(double t_s) const {
  if (t_s <= 0.0 || t_s >= duration_s()) {
    return 0.0;
  }
  if (t_s < tw_s) {
    return window_derivative_per_s(kind, t_s - tw_s, tw_s);
  }
  if (t_s <= tw_s + ti_s) {
    return 0.0;
  }
  return window_derivative_per_s(kind, t_s - tw_s - ti_s, tw_s);
}

}  // namespace pmsm::core
