// The Blackman window B (Eq. 23) and the modified window B2 (Eq. 24) that shape the edges of
// an injection pulse, their time derivatives, and the constants the paper quotes for them
// (Eqs. 25-28), computed here numerically rather than typed in.
//
// tn is time measured from the centre of the window, -Tw <= tn <= Tw; the window is 1 at
// tn = 0 and 0 at tn = +-Tw. A pulse uses the rising half (tn from -Tw to 0) as its leading
// edge and the falling half as its trailing edge (docs/equations.md).
#pragma once

#include <string_view>

namespace pmsm::core {

enum class WindowKind { kBlackman, kModifiedBlackman };

[[nodiscard]] std::string_view to_string(WindowKind kind);

// The window period (each edge): the paper's 4 ms, the default where the machine's inductance
// allows it (default_window_period_s), and the longest injection.Tw_s takes (a longer edge
// leaves no time to record).
inline constexpr double kPaperWindowPeriod_s = 0.004;
inline constexpr double kMaxWindowPeriod_s = 1.0;

// Eq. 23 (B) or Eq. 24 (B2); zero outside |tn| <= Tw.
[[nodiscard]] double window_value(WindowKind kind, double tn_s, double tw_s);

// d/dt of Eq. 23 or Eq. 24, per second; zero outside |tn| <= Tw.
[[nodiscard]] double window_derivative_per_s(WindowKind kind, double tn_s, double tw_s);

struct WindowConstants {
  double max_slope_times_tw = 0.0;      // max |dB/dt| * Tw  (Eqs. 25-26: 1.81, 2.04)
  double integral_per_tw = 0.0;         // integral of B over [-Tw, Tw] / Tw (Eqs. 27-28: 0.84, 1.25)
  double integral_squared_per_tw = 0.0; // integral of B^2 over [-Tw, Tw] / Tw (exact pulse energy)
};

// Computes the constants by dense sampling, golden-section refinement and Simpson's rule
// (about 1.3 million instructions: never in a control period).
[[nodiscard]] WindowConstants compute_window_constants(WindowKind kind);

// The same constants, computed once per process for both windows (on the first call) and
// looked up afterwards. The injection scheduler calls it at construction, so that no control
// period pays for the computation.
[[nodiscard]] const WindowConstants& window_constants(WindowKind kind);

// Envelope of one injection pulse that starts at t = 0: a rising window edge of duration Tw,
// a flat top of duration Ti at 1, and a falling window edge of duration Tw (Section VIII,
// "multiplying the window function in a piecewise manner with the injection currents").
struct PulseEnvelope {
  WindowKind kind = WindowKind::kBlackman;
  double tw_s = 0.01;
  double ti_s = 0.1;

  [[nodiscard]] double duration_s() const { return 2.0 * tw_s + ti_s; }
  [[nodiscard]] double value(double t_s) const;
  [[nodiscard]] double derivative_per_s(double t_s) const;
  [[nodiscard]] bool in_flat_top(double t_s) const { return t_s >= tw_s && t_s <= tw_s + ti_s; }
};

}  // namespace pmsm::core
