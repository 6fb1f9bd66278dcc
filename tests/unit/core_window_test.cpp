#include <gtest/gtest.h>

#include <cmath>

#include "pmsm/core/window.hpp"

namespace pmsm::core {
namespace {

TEST(Window, PaperConstantsEqs25To28) {
  const WindowConstants b = compute_window_constants(WindowKind::kBlackman);
  const WindowConstants b2 = compute_window_constants(WindowKind::kModifiedBlackman);
  // The paper quotes two decimals.
  EXPECT_NEAR(b.max_slope_times_tw, 1.81, 0.005);   // Eq. 25
  EXPECT_NEAR(b2.max_slope_times_tw, 2.04, 0.005);  // Eq. 26
  EXPECT_NEAR(b.integral_per_tw, 0.84, 0.005);      // Eq. 27
  EXPECT_NEAR(b2.integral_per_tw, 1.25, 0.005);     // Eq. 28
  // Integral of B^2 over [-Tw, Tw]: 2 (a0^2 + a1^2/2 + a2^2/2) Tw.
  EXPECT_NEAR(b.integral_squared_per_tw, 2.0 * (0.42 * 0.42 + 0.125 + 0.0032), 1e-9);
  EXPECT_NEAR(b2.integral_squared_per_tw, 2.0 * (0.625 * 0.625 + 0.125 + 0.0078125), 1e-9);
}

TEST(Window, ShapeAndDerivative) {
  const double tw = 0.02;
  for (WindowKind kind : {WindowKind::kBlackman, WindowKind::kModifiedBlackman}) {
    EXPECT_NEAR(window_value(kind, 0.0, tw), 1.0, 1e-12);
    EXPECT_NEAR(window_value(kind, tw, tw), 0.0, 1e-12);
    EXPECT_NEAR(window_value(kind, -tw, tw), 0.0, 1e-12);
    EXPECT_EQ(window_value(kind, 1.5 * tw, tw), 0.0);
    // Derivative against a central difference.
    for (double tn : {-0.017, -0.009, -0.001, 0.004, 0.015}) {
      const double h = 1e-8;
      const double numeric = (window_value(kind, tn + h, tw) - window_value(kind, tn - h, tw)) / (2 * h);
      EXPECT_NEAR(window_derivative_per_s(kind, tn, tw), numeric, 1e-4);
    }
  }
  // The modified window's slope is zero at the centre (where it meets the flat top) and its
  // second derivative too, unlike the standard one (Section VII).
  const double h = 1e-6;
  const double b_curvature = (window_derivative_per_s(WindowKind::kBlackman, h, tw) -
                              window_derivative_per_s(WindowKind::kBlackman, -h, tw)) / (2 * h);
  const double b2_curvature = (window_derivative_per_s(WindowKind::kModifiedBlackman, h, tw) -
                               window_derivative_per_s(WindowKind::kModifiedBlackman, -h, tw)) / (2 * h);
  EXPECT_GT(std::abs(b_curvature), 100.0);
  EXPECT_LT(std::abs(b2_curvature), 1e-3 * std::abs(b_curvature));
}

TEST(Window, PulseEnvelopeIsContinuousAndIntegratesToTheConstants) {
  const PulseEnvelope env{WindowKind::kBlackman, 0.01, 0.05};
  EXPECT_DOUBLE_EQ(env.duration_s(), 0.07);
  EXPECT_NEAR(env.value(0.0), 0.0, 1e-12);
  EXPECT_NEAR(env.value(0.01), 1.0, 1e-12);
  EXPECT_NEAR(env.value(0.035), 1.0, 1e-12);
  EXPECT_NEAR(env.value(0.0600001), 1.0, 1e-6);
  EXPECT_NEAR(env.value(0.07), 0.0, 1e-12);
  EXPECT_TRUE(env.in_flat_top(0.03));
  EXPECT_FALSE(env.in_flat_top(0.005));
  // Integral of the whole pulse = Ti + 0.84 Tw (the bracket of Eq. 32), by the midpoint rule.
  double sum = 0.0;
  const int n = 700000;
  for (int k = 0; k < n; ++k) {
    sum += env.value((k + 0.5) * env.duration_s() / n);
  }
  EXPECT_NEAR(sum * env.duration_s() / n, 0.05 + 0.84 * 0.01, 1e-5);
}

}  // namespace
}  // namespace pmsm::core
