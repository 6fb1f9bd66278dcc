// Reproducible Gaussian noise: std::mt19937_64 (whose output sequence the standard fixes)
// and our own Box–Muller transform, because std::normal_distribution's algorithm differs
// between standard libraries. The same seed gives a bit-identical stream everywhere.
#pragma once

#include <cmath>
#include <cstdint>
#include <numbers>
#include <random>

namespace pmsm::plant {

class GaussianRng {
 public:
  explicit GaussianRng(std::uint64_t seed) : engine_(seed) {}

  // Uniform on the open interval (0, 1): 53 random bits, offset by half a step so that
  // log() never sees 0.
  double uniform_open() {
    constexpr double kScale = 1.0 / 9007199254740992.0;  // 2^-53
    return (static_cast<double>(engine_() >> 11U) + 0.5) * kScale;
  }

  // Standard normal deviate; Box–Muller yields pairs, the second one is cached.
  double standard_normal() {
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    const double u1 = uniform_open();
    const double u2 = uniform_open();
    const double radius = std::sqrt(-2.0 * std::log(u1));
    const double angle = 2.0 * std::numbers::pi * u2;
    spare_ = radius * std::sin(angle);
    has_spare_ = true;
    return radius * std::cos(angle);
  }

 private:
  std::mt19937_64 engine_;
  double spare_ = 0.0;
  bool has_spare_ = false;
};

}  // namespace pmsm::plant
