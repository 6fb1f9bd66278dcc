// The simulator's memory of the plant's truth over the last seconds (tools/sim/runner.cpp).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <vector>

namespace pmsm::app {

// The plant's resistance and winding temperature over the last seconds, recorded at the
// runner's fast rate (every 10 periods: 1 ms at 10 kHz PWM, 0.5 ms at 20 kHz) into a ring
// allocated once, so that a published estimate is compared with the truth at the time it
// belongs to (its pairs' weighted mean time), not at its publication: an event lasts up to
// seconds, and a winding cooling at 9 K/s after a load step (the 30 mOhm IPM's heat-up at 40x
// thermal time) moves by 2 K in 0.2 s.
class TruthHistory {
 public:
  static constexpr std::size_t kSize = std::size_t{1} << 15;  // 32.8 s at 1 kHz, 16.4 s at 2 kHz

  TruthHistory() : time_s_(kSize), rs_ohm_(kSize), winding_C_(kSize) {}

  // Records come in time order (an extra one between the regular ones is fine); one that
  // would go back in time, or is no number, is dropped, so the search's order holds.
  void record(double time_s, double rs_ohm, double winding_C) {
    if (!std::isfinite(time_s) || (count_ > 0 && time_s < time_s_[(count_ - 1) % kSize])) {
      return;
    }
    const std::size_t i = count_ % kSize;
    time_s_[i] = time_s;
    rs_ohm_[i] = rs_ohm;
    winding_C_[i] = winding_C;
    ++count_;
  }

  struct Point {
    double rs_ohm;
    double winding_C;
  };

  // Linear interpolation at time_s; NaN outside what the ring holds (older than its length,
  // or later than the last record).
  [[nodiscard]] Point at(double time_s) const {
    constexpr double kNoValue = std::numeric_limits<double>::quiet_NaN();
    constexpr Point kNone{kNoValue, kNoValue};
    if (count_ == 0 || !std::isfinite(time_s)) {
      return kNone;
    }
    const std::size_t held = std::min<std::size_t>(count_, kSize);
    const std::size_t first = count_ - held;  // the oldest record still held
    auto t = [&](std::size_t n) { return time_s_[n % kSize]; };
    if (time_s < t(first) || time_s > t(count_ - 1)) {
      return kNone;
    }
    // The first record later than or at time_s (records are in time order).
    std::size_t lo = first;
    std::size_t hi = count_ - 1;
    while (lo < hi) {
      const std::size_t mid = lo + (hi - lo) / 2;
      if (t(mid) < time_s) {
        lo = mid + 1;
      } else {
        hi = mid;
      }
    }
    const std::size_t b = lo % kSize;
    if (lo == first || t(lo) == time_s) {
      return {rs_ohm_[b], winding_C_[b]};
    }
    const std::size_t a = (lo - 1) % kSize;
    const double w = (time_s - time_s_[a]) / (time_s_[b] - time_s_[a]);
    return {rs_ohm_[a] + w * (rs_ohm_[b] - rs_ohm_[a]), winding_C_[a] + w * (winding_C_[b] - winding_C_[a])};
  }

 private:
  std::vector<double> time_s_;
  std::vector<double> rs_ohm_;
  std::vector<double> winding_C_;
  std::size_t count_ = 0;
};

}  // namespace pmsm::app
