#include "pmsm/core/inverter_sweep.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "pmsm/core/modulation.hpp"

namespace pmsm::core {
namespace {

// Level magnitudes as fractions of max_current_A: three inside a typical band (a PWM ripple of
// a few per cent of the rated current), three well outside it.
constexpr std::array<double, InverterSweep::kLevels / 2> kMagnitudes{0.03, 0.06, 0.1, 0.2, 0.5, 1.0};

}  // namespace

const char* to_string(InverterSweepOutcome outcome) {
  switch (outcome) {
    case InverterSweepOutcome::kNone: return "none";
    case InverterSweepOutcome::kMeasured: return "measured";
    case InverterSweepOutcome::kAborted: return "aborted";
    case InverterSweepOutcome::kSpeedChanged: return "speed_changed";
    case InverterSweepOutcome::kVoltageLimited: return "voltage_limited";
    case InverterSweepOutcome::kBandAtLimit: return "band_at_limit";
    case InverterSweepOutcome::kImplausible: return "implausible";
    case InverterSweepOutcome::kUnresolved: return "unresolved";
  }
  return "unknown";
}

void InverterSweep::start(const InverterSweepConfig& config, double period_s) {
  config_ = config;
  period_s_ = period_s;
  stage_ = Stage::kSettle;
  level_ = 0;
  elapsed_s_ = 0.0;
  ring_count_ = 0;
  ring_head_ = 0;
  result_ = {};
  for (int k = 0; k < kBands; ++k) {
    bands_[static_cast<std::size_t>(k)] = band_candidate_A(k);
  }
}

void InverterSweep::stop(InverterSweepOutcome outcome) {
  stage_ = Stage::kIdle;
  result_ = {};
  result_.outcome = outcome;
}

void InverterSweep::abort() {
  if (active()) {
    stop(InverterSweepOutcome::kAborted);
  }
}

double InverterSweep::level_A(int level) const {
  const double sign = (level % 2 == 0) ? 1.0 : -1.0;
  return sign * kMagnitudes[static_cast<std::size_t>(level / 2)] * config_.max_current_A;
}

double InverterSweep::band_candidate_A(int k) const {
  const double lo = kBandMinFraction * config_.max_current_A;
  const double ratio = std::pow(kBandMaxFraction / kBandMinFraction, 1.0 / (kBands - 1));
  return lo * std::pow(ratio, k);
}

double InverterSweep::id_ref_A() const {
  return (stage_ == Stage::kSettle || stage_ == Stage::kAverage) ? level_A(level_) : 0.0;
}

bool InverterSweep::step(bool enabled, const Abc& i_A, const Rotation& mid, double vd_V, double id_A,
                         double omega_e_rad_s, bool voltage_limited) {
  if (stage_ == Stage::kIdle) {
    return false;
  }
  if (!enabled || !std::isfinite(vd_V) || !std::isfinite(id_A) || !std::isfinite(omega_e_rad_s) ||
      !std::isfinite(i_A.a) || !std::isfinite(i_A.b) || !std::isfinite(i_A.c)) {
    abort();
    return true;
  }
  if (voltage_limited && stage_ == Stage::kAverage) {
    // The command was not what the bridge applied: the level's mean would be wrong.
    stage_ = Stage::kIdle;
    result_ = {};
    result_.outcome = InverterSweepOutcome::kVoltageLimited;
    return true;
  }
  ring_i_[static_cast<std::size_t>(ring_head_)] = i_A;
  ring_mid_[static_cast<std::size_t>(ring_head_)] = mid;
  ring_head_ = (ring_head_ + 1) % kRing;
  ring_count_ = std::min(ring_count_ + 1, kRing);
  switch (stage_) {
    case Stage::kSettle:
      elapsed_s_ += period_s_;
      if (elapsed_s_ >= config_.settle_s) {
        stage_ = Stage::kAverage;
        elapsed_s_ = 0.0;
        angle_rad_ = 0.0;
        count_ = 0;
        sum_vd_ = sum_id_ = sum_omega_ = 0.0;
        sum_gd_.fill(0.0);
      }
      return false;
    case Stage::kAverage: {
      sum_vd_ += vd_V;
      sum_id_ += id_A;
      sum_omega_ += omega_e_rad_s;
      if (ring_count_ == kRing) {
        // The period whose end is the centre of the newest kSmooth samples: its two ends'
        // centred averages (the oldest kSmooth and the newest kSmooth of the ring) and its mid
        // rotation.
        Abc i0{};
        Abc i1{};
        for (int j = 0; j < kSmooth; ++j) {
          const Abc& older = ring_i_[static_cast<std::size_t>((ring_head_ + j) % kRing)];
          const Abc& newer = ring_i_[static_cast<std::size_t>((ring_head_ + j + 1) % kRing)];
          i0 = {i0.a + older.a, i0.b + older.b, i0.c + older.c};
          i1 = {i1.a + newer.a, i1.b + newer.b, i1.c + newer.c};
        }
        constexpr double kInv = 1.0 / kSmooth;
        i0 = {i0.a * kInv, i0.b * kInv, i0.c * kInv};
        i1 = {i1.a * kInv, i1.b * kInv, i1.c * kInv};
        const Rotation& centre = ring_mid_[static_cast<std::size_t>((ring_head_ + kSmooth / 2 + 1) % kRing)];
        for (int k = 0; k < kBands; ++k) {
          // The same pattern as the estimator's (drive_controller.cpp), for band k.
          const double b = bands_[static_cast<std::size_t>(k)];
          const Abc sign{mean_soft_sign(i0.a, i1.a, b), mean_soft_sign(i0.b, i1.b, b), mean_soft_sign(i0.c, i1.c, b)};
          sum_gd_[static_cast<std::size_t>(k)] += park(clarke(sign), centre.c, centre.s).d;
        }
      }
      if (count_ == 0) {
        // Whole electrical turns when turning (the EMF's harmonics, the cogging and the ripple
        // they cause average out): the number of turns nearest to average_s, at least one;
        // below half a turn in average_s, the time alone.
        const double turns = std::abs(omega_e_rad_s) * config_.average_s / kTwoPi;
        target_angle_rad_ = turns >= 0.5 ? kTwoPi * std::max(1.0, std::round(turns)) : 0.0;
      }
      ++count_;
      elapsed_s_ += period_s_;
      angle_rad_ += std::abs(omega_e_rad_s) * period_s_;
      const bool done = target_angle_rad_ > 0.0 ? angle_rad_ >= target_angle_rad_ - 0.5 * std::abs(omega_e_rad_s) * period_s_
                                                : elapsed_s_ >= config_.average_s;
      if (done || elapsed_s_ >= 3.0 * config_.average_s) {
        finish_level();
      }
      return false;
    }
    case Stage::kFit:
      fit_step();
      if (fit_index_ >= kBands + kGoldenSteps + 3) {
        conclude();
        stage_ = Stage::kIdle;
        return true;
      }
      return false;
    case Stage::kIdle:
      break;
  }
  return false;
}

void InverterSweep::finish_level() {
  const double n = static_cast<double>(std::max(count_, 1));
  const auto l = static_cast<std::size_t>(level_);
  mean_vd_[l] = sum_vd_ / n;
  mean_id_[l] = sum_id_ / n;
  for (std::size_t k = 0; k < kBands; ++k) {
    mean_gd_[l][k] = sum_gd_[k] / n;
  }
  const double speed = std::abs(sum_omega_ / n);
  speed_min_ = level_ > 0 ? std::min(speed_min_, speed) : speed;
  speed_max_ = level_ > 0 ? std::max(speed_max_, speed) : speed;
  ++level_;
  elapsed_s_ = 0.0;
  if (level_ >= kLevels) {
    stage_ = Stage::kFit;
    fit_index_ = 0;
  } else {
    stage_ = Stage::kSettle;
  }
}

InverterSweep::LevelFit InverterSweep::fit_levels(double x, int centre) const {
  // <Gd> at a continuous band index x: quadratic interpolation through the candidates
  // centre - 1, centre, centre + 1 (the pattern is smooth in log b), so that the band is not
  // limited to the grid. One centre for a whole search keeps the residual continuous in x.
  const double u = x - centre;
  const double w_minus = 0.5 * u * (u - 1.0);
  const double w_zero = 1.0 - u * u;
  const double w_plus = 0.5 * u * (u + 1.0);
  const auto c = static_cast<std::size_t>(centre);
  std::array<double, kLevels> gd{};
  for (std::size_t l = 0; l < kLevels; ++l) {
    gd[l] = w_minus * mean_gd_[l][c - 1] + w_zero * mean_gd_[l][c] + w_plus * mean_gd_[l][c + 1];
  }
  // Least squares of <vd> = Rs <id> + Vx <Gd> + c over the levels, through the 3x3 normal
  // equations and their adjugate (the inverse's (Vx, Vx) element is the variance factor).
  LevelFit f;
  std::array<std::array<double, 3>, 3> a{};
  std::array<double, 3> r{};
  for (std::size_t l = 0; l < kLevels; ++l) {
    const std::array<double, 3> row{mean_id_[l], gd[l], 1.0};
    for (std::size_t i = 0; i < 3; ++i) {
      for (std::size_t j = 0; j < 3; ++j) {
        a[i][j] += row[i] * row[j];
      }
      r[i] += row[i] * mean_vd_[l];
    }
  }
  std::array<std::array<double, 3>, 3> adj{};
  adj[0][0] = a[1][1] * a[2][2] - a[1][2] * a[2][1];
  adj[0][1] = a[0][2] * a[2][1] - a[0][1] * a[2][2];
  adj[0][2] = a[0][1] * a[1][2] - a[0][2] * a[1][1];
  adj[1][0] = a[1][2] * a[2][0] - a[1][0] * a[2][2];
  adj[1][1] = a[0][0] * a[2][2] - a[0][2] * a[2][0];
  adj[1][2] = a[0][2] * a[1][0] - a[0][0] * a[1][2];
  adj[2][0] = a[1][0] * a[2][1] - a[1][1] * a[2][0];
  adj[2][1] = a[0][1] * a[2][0] - a[0][0] * a[2][1];
  adj[2][2] = a[0][0] * a[1][1] - a[0][1] * a[1][0];
  const double det = a[0][0] * adj[0][0] + a[0][1] * adj[1][0] + a[0][2] * adj[2][0];
  const double scale = a[0][0] * a[1][1] * a[2][2];
  if (!(std::abs(det) > 1e-12 * scale) || !std::isfinite(det)) {
    return f;
  }
  std::array<double, 3> beta{};
  for (std::size_t i = 0; i < 3; ++i) {
    beta[i] = (adj[i][0] * r[0] + adj[i][1] * r[1] + adj[i][2] * r[2]) / det;
  }
  for (std::size_t l = 0; l < kLevels; ++l) {
    const double e = mean_vd_[l] - (beta[0] * mean_id_[l] + beta[1] * gd[l] + beta[2]);
    f.sse += e * e;
  }
  f.valid = std::isfinite(f.sse);
  f.rs_ohm = beta[0];
  f.vx_V = beta[1];
  f.offset_V = beta[2];
  f.vx_var = f.sse / (kLevels - 4) * adj[1][1] / det;  // Rs, Vx, c and the band fitted
  return f;
}

void InverterSweep::fit_step() {
  // One least-squares fit a period: first every grid band, then a golden-section search of the
  // continuous band index between the best one's neighbours, then the optimum and its two
  // sides, which give the band's uncertainty. A singular fit counts as an infinite residual.
  constexpr double kGolden = 0.6180339887498949;
  const auto residual_at = [this](double x, int centre) {
    const LevelFit f = fit_levels(x, centre);
    return f.valid ? f.sse : std::numeric_limits<double>::infinity();
  };
  const auto residual = [&](double x) { return residual_at(x, centre_); };
  if (fit_index_ < kBands) {
    const int k = fit_index_;
    grid_sse_[static_cast<std::size_t>(k)] = residual_at(static_cast<double>(k), std::clamp(k, 1, kBands - 2));
    if (++fit_index_ == kBands) {
      best_grid_ = static_cast<int>(std::min_element(grid_sse_.begin(), grid_sse_.end()) - grid_sse_.begin());
      centre_ = std::clamp(best_grid_, 1, kBands - 2);
      lo_ = std::max(best_grid_ - 1, 0);
      hi_ = std::min(best_grid_ + 1, kBands - 1);
      x1_ = hi_ - kGolden * (hi_ - lo_);
      x2_ = lo_ + kGolden * (hi_ - lo_);
      f1_ = std::numeric_limits<double>::quiet_NaN();  // each evaluated in a period of its own
      f2_ = std::numeric_limits<double>::quiet_NaN();
    }
    return;
  }
  if (fit_index_ < kBands + kGoldenSteps) {
    if (std::isnan(f1_)) {
      f1_ = residual(x1_);
    } else if (std::isnan(f2_)) {
      f2_ = residual(x2_);
    } else if (f1_ < f2_) {
      hi_ = x2_;
      x2_ = x1_;
      f2_ = f1_;
      x1_ = hi_ - kGolden * (hi_ - lo_);
      f1_ = residual(x1_);
    } else {
      lo_ = x1_;
      x1_ = x2_;
      f1_ = f2_;
      x2_ = lo_ + kGolden * (hi_ - lo_);
      f2_ = residual(x2_);
    }
    ++fit_index_;
    return;
  }
  const double x = 0.5 * (lo_ + hi_);
  const int k = fit_index_ - kBands - kGoldenSteps;
  constexpr double kH = 0.1;  // grid steps, for the finite differences
  side_[static_cast<std::size_t>(k)] = fit_levels(k == 0 ? x - kH : (k == 1 ? x + kH : x), centre_);
  ++fit_index_;
}

void InverterSweep::conclude() {
  constexpr double kH = 0.1;
  InverterSweepResult res;
  const LevelFit& minus = side_[0];
  const LevelFit& plus = side_[1];
  const LevelFit& best = side_[2];
  const double x = 0.5 * (lo_ + hi_);
  if (!best.valid || !minus.valid || !plus.valid) {
    res.outcome = InverterSweepOutcome::kImplausible;
    result_ = res;
    return;
  }
  res.fitted = true;
  res.vx_V = best.vx_V;
  res.rs_ohm = best.rs_ohm;
  res.offset_V = best.offset_V;
  res.band_A = bands_[0] * std::pow(kBandMaxFraction / kBandMinFraction, x / (kBands - 1));
  res.residual_rms_V = std::sqrt(best.sse / kLevels);
  // The band's own uncertainty from the residual's curvature in the band index
  // (var_x = 2 s^2 / SSE''), carried into Vx through dVx/dx, added to the fit's variance.
  const double s2 = best.sse / (kLevels - 4);
  const double curvature = (minus.sse - 2.0 * best.sse + plus.sse) / (kH * kH);
  const double dvx_dx = (plus.vx_V - minus.vx_V) / (2.0 * kH);
  const double var_x = curvature > 0.0 ? 2.0 * s2 / curvature : 1.0;
  res.vx_std_V = std::sqrt(std::max(best.vx_var, 0.0) + dvx_dx * dvx_dx * var_x);

  const double speed_allowed = config_.max_speed_change_rad_s + 0.05 * speed_max_;
  if (speed_max_ - speed_min_ > speed_allowed) {
    res.outcome = InverterSweepOutcome::kSpeedChanged;
  } else if (std::isfinite(res.vx_V) && std::isfinite(res.vx_std_V) && res.vx_std_V > kMaxVxStdFraction * std::abs(res.vx_V)) {
    // The band is what the small levels' pattern shows, and only where their current vector
    // passes near zero; and the even term c, -w Lq iq, is taken as one for all twelve levels. A
    // q current that moved between them (a speed ramp's torque ending under the sweep) breaks
    // both, and Vx's error bar says so; such a Vx may come out of either sign, so this comes
    // before the sign test (and before band_at_limit: a band at the range's end is only
    // reported as such when the fit resolved Vx).
    res.outcome = InverterSweepOutcome::kUnresolved;
  } else if (!(res.vx_V > 0.0) || !(res.rs_ohm > 0.0) || !std::isfinite(res.vx_V) || !std::isfinite(res.vx_std_V) ||
             !std::isfinite(res.band_A)) {
    res.outcome = InverterSweepOutcome::kImplausible;
  } else if (best_grid_ == 0 || best_grid_ == kBands - 1) {
    res.outcome = InverterSweepOutcome::kBandAtLimit;
  } else {
    res.outcome = InverterSweepOutcome::kMeasured;
  }
  result_ = res;
}

}  // namespace pmsm::core
