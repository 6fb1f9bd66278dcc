// Back-EMF waveform with harmonics (paper Fig. 11: sinusoidal, modular and trapezoidal
// machines with 100 %, 89 % and 77 % fundamental).
//
// The phase-a EMF is e_a = omega_e·psi_m·f(theta_e) with
//   f(theta) = -sum_n b_n·sin(n·theta),  b_1 = 1,
// so that a purely sinusoidal machine has e_q = omega_e·psi_m (Eq. 3's Ke·omega_m term).
// Only odd, non-triplen orders are used: with a star-connected winding and an isolated
// neutral, triplen harmonics are zero-sequence and drive no current. In the rotor frame the
// harmonic pair 6k±1 appears as the rotor-angle-dependent terms kd(theta), kq(theta) of
// Eqs. 33-36, at 6k times the electrical angle.
#pragma once

#include <array>
#include <cstddef>
#include <span>

#include "pmsm/plant/config.hpp"

namespace pmsm::plant {

struct EmfHarmonic {
  int order = 0;          // n, odd and not a multiple of 3
  double amplitude = 0.0;  // b_n relative to the fundamental
};

inline constexpr std::size_t kMaxEmfHarmonics = 12;
// The highest harmonic order a custom shape may name (plant.emf.harmonic_orders), and the
// highest multiple k of 6·theta it reaches in the rotor frame (k = (n + 1) / 6).
inline constexpr int kMaxEmfOrder = 99;
inline constexpr std::size_t kMaxEmfSixMultiple = (kMaxEmfOrder + 1) / 6;

// Harmonic spectra of the built-in shapes (empty for sinusoidal and custom).
std::span<const EmfHarmonic> builtin_emf_harmonics(EmfShape shape);

class EmfModel {
 public:
  explicit EmfModel(const EmfConfig& config);

  // f(theta): phase-a EMF divided by omega_e·psi_m.
  [[nodiscard]] double phase_shape(double theta_e_rad) const;

  // Rotor-frame EMF divided by omega_e·psi_m: e_d = omega_e·psi_m·g_d, e_q = omega_e·psi_m·g_q.
  void dq_shape(double theta_e_rad, double& g_d, double& g_q) const;
  // The same from cos(theta) and sin(theta), which the caller already has (no trigonometry).
  void dq_shape(double cos_theta, double sin_theta, double& g_d, double& g_q) const;

  // Upper bound of |f(theta)|: 1 + sum |b_n|.
  [[nodiscard]] double peak_bound() const { return peak_bound_; }

  // Fundamental amplitude divided by the waveform's peak, from the spectrum.
  [[nodiscard]] double fundamental_fraction() const;

  [[nodiscard]] std::span<const EmfHarmonic> harmonics() const {
    return {harmonics_.data(), count_};
  }

 private:
  std::array<EmfHarmonic, kMaxEmfHarmonics> harmonics_{};
  // Per harmonic, in the order given: its amplitude b_n, the same with the sign of its q-axis
  // term (+b_n for n = 6k+1, -b_n for n = 6k-1), and the multiple k of 6·theta it appears at
  // in the rotor frame.
  struct RotorTerm {
    double d_weight = 0.0;
    double q_weight = 0.0;
    std::size_t six_multiple = 0;
  };
  std::array<RotorTerm, kMaxEmfHarmonics> terms_{};
  std::size_t count_ = 0;
  std::size_t max_six_multiple_ = 0;
  double peak_bound_ = 1.0;
};

}  // namespace pmsm::plant
