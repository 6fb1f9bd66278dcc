#include "pmsm/core/pair_estimator.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <optional>

namespace pmsm::core {
namespace {

// Four-point Lagrange interpolation at x, for samples at coordinates c[0..3] (the bracket is
// c[1]..c[2]). The recorded signals carry EMF harmonics with only a handful of samples per
// cycle at speed; linear interpolation attenuates them by several per cent, always in the
// same direction, and the residual correlates with the six-step dead-time pattern. The cubic
// keeps that error an order of magnitude smaller.
struct Weights {
  std::array<double, 4> w{};
};

Weights lagrange_weights(const std::array<double, 4>& c, double x) {
  // w_j = prod_{m != j} (x - c_m) / (c_j - c_m), written out: the six differences of the
  // nodes once, four divisions (a loop with a skip test cost four times the instructions).
  const double x0 = x - c[0];
  const double x1 = x - c[1];
  const double x2 = x - c[2];
  const double x3 = x - c[3];
  const double d01 = c[0] - c[1];
  const double d02 = c[0] - c[2];
  const double d03 = c[0] - c[3];
  const double d12 = c[1] - c[2];
  const double d13 = c[1] - c[3];
  const double d23 = c[2] - c[3];
  Weights out;
  out.w[0] = (x1 * x2 * x3) / (d01 * d02 * d03);
  out.w[1] = (x0 * x2 * x3) / (-d01 * d12 * d13);
  out.w[2] = (x0 * x1 * x3) / (d02 * d12 * d23);
  out.w[3] = (x0 * x1 * x2) / (-d03 * -d13 * -d23);
  return out;
}

struct Solution {
  Eigen::Vector3d theta = Eigen::Vector3d::Zero();
  double rcond = 0.0;  // only when asked for (the whole fit's condition guard)
  double rss = 0.0;
};

// When a unit-diagonal normal matrix counts as singular: never when its reciprocal condition
// is above 1e-12 by the old check's standard, but told without the eigenvalues. Its largest
// eigenvalue is at least 1 (the diagonal), so a pivot at or below 1e-12 (each bounds the
// smallest eigenvalue from above) means singular. Pivots above it are not enough the other way;
// the determinant, the product of the pivots, is: the other two eigenvalues sum to at most 3
// (the trace), so their product is at most 2.25, the smallest is at least det / 2.25, the
// largest at most 3, and det > 6.75e-12 makes the reciprocal condition above 1e-12. (A few
// matrices with a reciprocal condition just above 1e-12 are refused that the old check took.)
constexpr double kMinPivot = 1e-12;
constexpr double kMinDeterminant = 6.75e-12;

// Solves a symmetric positive-definite 3x3 system a z = b by Cholesky, written out: a
// quarter of the instructions of Eigen's pivoted LDLT on a matrix this small, and the
// jackknife solves seventeen such systems in one control period (the worst-case step,
// docs/performance.md). False if the matrix is singular in the sense of kMinDeterminant.
bool cholesky_solve3(const Eigen::Matrix3d& a, const Eigen::Vector3d& b, Eigen::Vector3d& z) {
  const double d0 = a(0, 0);
  if (!(d0 > kMinPivot)) {
    return false;
  }
  const double l00 = std::sqrt(d0);
  const double l10 = a(1, 0) / l00;
  const double l20 = a(2, 0) / l00;
  const double d1 = a(1, 1) - l10 * l10;
  if (!(d1 > kMinPivot)) {
    return false;
  }
  const double l11 = std::sqrt(d1);
  const double l21 = (a(2, 1) - l20 * l10) / l11;
  const double d2 = a(2, 2) - l20 * l20 - l21 * l21;
  if (!(d2 > kMinPivot) || !(d0 * d1 * d2 > kMinDeterminant)) {
    return false;
  }
  const double l22 = std::sqrt(d2);
  // L y = b, then L' z = y.
  const double y0 = b(0) / l00;
  const double y1 = (b(1) - l10 * y0) / l11;
  const double y2 = (b(2) - l20 * y0 - l21 * y1) / l22;
  z(2) = y2 / l22;
  z(1) = (y1 - l21 * z(2)) / l11;
  z(0) = (y0 - l10 * z(1) - l20 * z(2)) / l00;
  return true;
}

// Solves the normal equations for the active regressors with the others held at `fixed`.
// With `condition`, also the reciprocal condition of the scaled normal matrix (its
// eigenvalues in closed form), which the whole fit reports and guards on; the jackknife's
// leave-one-block-out solves need only to know that the matrix is not singular.
bool solve_sums(const FitSums& s, const std::array<bool, kRegressors>& active,
                const Eigen::Vector3d& fixed, bool condition, Solution& out) {
  // Move the fixed regressors to the left side: y' = y - sum_j fixed_j x_j.
  Eigen::Matrix3d xtx;
  Eigen::Vector3d xty;
  for (int r = 0; r < kRegressors; ++r) {
    for (int c = 0; c < kRegressors; ++c) {
      xtx(r, c) = s.xtx[static_cast<std::size_t>(r)][static_cast<std::size_t>(c)];
    }
    xty(r) = s.xty[static_cast<std::size_t>(r)];
  }
  // A regressor with no excitation at all (a current that never changed, a pattern that
  // never moved) carries no information: leave it out rather than fail the whole fit. Rs's
  // own regressor is the exception: without it there is nothing to estimate.
  std::array<bool, kRegressors> use = active;
  for (int r = 1; r < kRegressors; ++r) {
    if (use[static_cast<std::size_t>(r)] && !(xtx(r, r) > 1e-12 * std::max(xtx(0, 0), 1e-300))) {
      use[static_cast<std::size_t>(r)] = false;
    }
  }
  Eigen::Vector3d f = Eigen::Vector3d::Zero();
  int p = 0;
  for (int r = 0; r < kRegressors; ++r) {
    if (use[static_cast<std::size_t>(r)]) {
      ++p;
    } else if (!active[static_cast<std::size_t>(r)]) {
      f(r) = fixed(r);
    }
  }
  if (s.n < 4.0 * p || p == 0) {
    return false;
  }
  const Eigen::Vector3d xty_adj = xty - xtx * f;
  const double yty_adj = s.yty - 2.0 * f.dot(xty) + f.dot(xtx * f);

  Eigen::Matrix3d a = Eigen::Matrix3d::Identity();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
  Eigen::Vector3d scale = Eigen::Vector3d::Ones();
  for (int r = 0; r < kRegressors; ++r) {
    if (!use[static_cast<std::size_t>(r)]) {
      continue;
    }
    if (xtx(r, r) <= 0.0) {
      return false;
    }
    scale(r) = 1.0 / std::sqrt(xtx(r, r));
    b(r) = xty_adj(r);
    for (int c = 0; c < kRegressors; ++c) {
      if (use[static_cast<std::size_t>(c)]) {
        a(r, c) = xtx(r, c);
      }
    }
  }
  // Scaled to unit diagonal: the condition says how collinear the regressors are, not how
  // different their units are. Inactive rows are identity.
  const Eigen::Matrix3d scaled = scale.asDiagonal() * a * scale.asDiagonal();
  if (condition) {
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
    eig.computeDirect(scaled, Eigen::EigenvaluesOnly);
    out.rcond = eig.eigenvalues().minCoeff() / eig.eigenvalues().maxCoeff();
    if (!(out.rcond > 1e-12)) {
      return false;
    }
  }
  Eigen::Vector3d z;
  if (!cholesky_solve3(scaled, scale.asDiagonal() * b, z)) {
    return false;
  }
  Eigen::Vector3d theta = scale.asDiagonal() * z;
  for (int r = 0; r < kRegressors; ++r) {
    if (!use[static_cast<std::size_t>(r)]) {
      theta(r) = 0.0;
    }
  }
  // RSS of the adjusted problem, y'y' - 2 t'X'y' + t'X'X t; theta is zero on inactive rows,
  // where `a` holds identity, so they do not contribute.
  out.rss = std::max(yty_adj - 2.0 * theta.dot(xty_adj) + theta.dot(a * theta), 0.0);
  out.theta = theta + f;
  return true;
}

}  // namespace

void FitSums::add(const std::array<double, kRegressors>& x, double y) {
  // Written out for the three regressors (the loops cost as much again as the arithmetic);
  // x[r] x[c] = x[c] x[r] exactly: each cross product once, added to both triangles.
  static_assert(kRegressors == 3, "FitSums::add is written out for three regressors");
  const double p01 = x[0] * x[1];
  const double p02 = x[0] * x[2];
  const double p12 = x[1] * x[2];
  xtx[0][0] += x[0] * x[0];
  xtx[0][1] += p01;
  xtx[0][2] += p02;
  xtx[1][0] += p01;
  xtx[1][1] += x[1] * x[1];
  xtx[1][2] += p12;
  xtx[2][0] += p02;
  xtx[2][1] += p12;
  xtx[2][2] += x[2] * x[2];
  xty[0] += x[0] * y;
  xty[1] += x[1] * y;
  xty[2] += x[2] * y;
  sum_x[0] += x[0];
  sum_x[1] += x[1];
  sum_x[2] += x[2];
  yty += y * y;
  sum_y += y;
  n += 1.0;
}

void FitSums::add(const FitSums& other, double sign) {
  for (std::size_t r = 0; r < kRegressors; ++r) {
    for (std::size_t c = 0; c < kRegressors; ++c) {
      xtx[r][c] += sign * other.xtx[r][c];
    }
    xty[r] += sign * other.xty[r];
    sum_x[r] += sign * other.sum_x[r];
  }
  yty += sign * other.yty;
  sum_y += sign * other.sum_y;
  n += sign * other.n;
}

void BlockedSums::add(const BlockedSums& other) {
  for (std::size_t b = 0; b < blocks.size(); ++b) {
    blocks[b].add(other.blocks[b]);
  }
  used = std::max(used, other.used);
}

FitSums BlockedSums::total() const {
  FitSums t;
  for (const FitSums& b : blocks) {
    t.add(b);
  }
  return t;
}

FitResult solve_fit(const BlockedSums& sums, const FitOptions& options) {
  FitResult out;
  const std::array<bool, kRegressors> active{true, options.fit_vx, options.fit_ld};
  const Eigen::Vector3d fixed(0.0, options.fixed_vx_V, 0.0);
  const FitSums total = sums.total();
  out.samples = total.n;
  if (total.n > 0.0) {
    out.signal_rms_A = std::sqrt(total.xtx[kRegRs][kRegRs] / total.n);
  }
  if (total.xtx[kRegRs][kRegRs] > 0.0) {
    out.drs_dvx = -total.xtx[kRegRs][kRegVx] / total.xtx[kRegRs][kRegRs];
    if (total.xtx[kRegVx][kRegVx] > 0.0) {
      const double rho_sq = total.xtx[kRegRs][kRegVx] * total.xtx[kRegRs][kRegVx] /
                            (total.xtx[kRegRs][kRegRs] * total.xtx[kRegVx][kRegVx]);
      out.vx_identifiability = 1.0 - rho_sq;
    }
  }
  Solution full;
  if (!solve_sums(total, active, fixed, true, full)) {
    return out;
  }
  out.rs_ohm = full.theta(kRegRs);
  out.vx_V = full.theta(kRegVx);
  out.ld_H = full.theta(kRegLd);
  out.condition = full.rcond;
  out.residual_rms_V = std::sqrt(full.rss / total.n);

  // Jackknife over blocks: samples within a recording are strongly correlated (the current
  // loop, the EMF harmonics), so the textbook standard error would be far too small.
  const int used = sums.used > 0 ? std::clamp(sums.used, 2, kFitBlocks) : kFitBlocks;
  std::array<Eigen::Vector2d, kFitBlocks> leave_out{};
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (int b = 0; b < used; ++b) {
    FitSums s = total;
    s.add(sums.blocks[static_cast<std::size_t>(b)], -1.0);
    Solution partial;
    if (!solve_sums(s, active, fixed, false, partial)) {
      return out;  // removing a block made the system singular: no honest error bar
    }
    leave_out[static_cast<std::size_t>(b)] = {partial.theta(kRegRs), partial.theta(kRegVx)};
    mean += leave_out[static_cast<std::size_t>(b)];
  }
  mean /= used;
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  for (int b = 0; b < used; ++b) {
    const Eigen::Vector2d d = leave_out[static_cast<std::size_t>(b)] - mean;
    cov += d * d.transpose();
  }
  cov *= static_cast<double>(used - 1) / used;
  out.var_rs = cov(0, 0);
  out.var_vx = options.fit_vx ? cov(1, 1) : 0.0;
  out.cov_rs_vx = options.fit_vx ? cov(0, 1) : 0.0;
  out.valid = std::isfinite(out.rs_ohm) && std::isfinite(out.var_rs);
  return out;
}

std::optional<PairMeans> pair_means(const BlockedSums& pair, bool fit_ld) {
  // A jackknife of block means would not do for the weight: for a fixed-angle pulse the
  // blocks are different parts of the pulse.
  const FitSums t = pair.total();
  if (t.n < 8.0) {
    return std::nullopt;
  }
  FitOptions own;
  own.fit_vx = false;
  own.fit_ld = fit_ld;
  const FitResult pair_fit = solve_fit(pair, own);
  if (!pair_fit.valid) {
    return std::nullopt;
  }
  PairMeans m;
  m.y = t.sum_y / t.n;
  m.x_rs = t.sum_x[kRegRs] / t.n;
  m.x_vx = t.sum_x[kRegVx] / t.n;
  m.w = 1.0 / std::max(pair_fit.var_rs * m.x_rs * m.x_rs, 1e-12);
  return m;
}

namespace {

// The weighted normal equations of the means, for Rs and Vx together ...
struct JointMeans {
  Eigen::Matrix2d a = Eigen::Matrix2d::Zero();
  Eigen::Vector2d b = Eigen::Vector2d::Zero();
  Eigen::Matrix2d design = Eigen::Matrix2d::Zero();  // the same, unweighted
  void add(const PairMeans& m) {
    const Eigen::Vector2d x(m.x_rs, m.x_vx);
    a += m.w * x * x.transpose();
    b += m.w * x * m.y;
    design += x * x.transpose();
  }
  [[nodiscard]] MeansFit solve() const {
    MeansFit out;
    if (!(a(0, 0) > 0.0) || !(a(1, 1) > 0.0)) {
      return out;
    }
    out.identifiability = 1.0 - a(0, 1) * a(0, 1) / (a(0, 0) * a(1, 1));
    if (!(out.identifiability > 1e-9)) {
      return out;
    }
    out.design_identifiability = 1.0 - design(0, 1) * design(0, 1) / (design(0, 0) * design(1, 1));
    const Eigen::Matrix2d cov = a.inverse();
    const Eigen::Vector2d theta = cov * b;
    out.rs_ohm = theta(0);
    out.vx_V = theta(1);
    out.var_rs = cov(0, 0);
    out.var_vx = cov(1, 1);
    out.cov_rs_vx = cov(0, 1);
    out.valid = std::isfinite(out.rs_ohm) && std::isfinite(out.vx_V);
    return out;
  }
};

// ... and for Rs with Vx held.
struct FixedVxMeans {
  double vx_V = 0.0;
  double sxx = 0.0;
  double sxg = 0.0;
  double sxy = 0.0;
  void add(const PairMeans& m) {
    sxx += m.w * m.x_rs * m.x_rs;
    sxg += m.w * m.x_rs * m.x_vx;
    sxy += m.w * m.x_rs * (m.y - vx_V * m.x_vx);
  }
  [[nodiscard]] MeansFit solve() const {
    MeansFit out;
    if (!(sxx > 0.0)) {
      return out;
    }
    out.rs_ohm = sxy / sxx;
    out.vx_V = vx_V;
    out.var_rs = 1.0 / sxx;
    out.drs_dvx = -sxg / sxx;
    out.valid = std::isfinite(out.rs_ohm);
    return out;
  }
};

template <typename Normal>
MeansFit means_fit(Normal normal, const BlockedSums* pairs, int count, bool fit_ld) {
  for (int j = 0; j < count; ++j) {
    if (const auto m = pair_means(pairs[j], fit_ld)) {
      normal.add(*m);
    }
  }
  return normal.solve();
}

template <typename Normal>
MeansFit means_fit(Normal normal, const std::optional<PairMeans>* means, int count) {
  for (int j = 0; j < count; ++j) {
    if (means[j]) {
      normal.add(*means[j]);
    }
  }
  return normal.solve();
}

}  // namespace

MeansFit solve_means_fit(const BlockedSums* pairs, int count, bool fit_ld) {
  return means_fit(JointMeans{}, pairs, count, fit_ld);
}

MeansFit solve_means_fit(const std::optional<PairMeans>* means, int count) {
  return means_fit(JointMeans{}, means, count);
}

MeansFit solve_means_fit_fixed_vx(const BlockedSums* pairs, int count, bool fit_ld, double vx_V) {
  return means_fit(FixedVxMeans{vx_V}, pairs, count, fit_ld);
}

MeansFit solve_means_fit_fixed_vx(const std::optional<PairMeans>* means, int count, double vx_V) {
  return means_fit(FixedVxMeans{vx_V}, means, count);
}

PairRecorder::PairRecorder(std::size_t capacity) : first_(capacity) {}

void PairRecorder::start(const PairFitConfig& config, MatchBy match_by, double direction) {
  config_ = config;
  if (!(config_.lq_incremental_H > 0.0)) {
    config_.lq_incremental_H = config_.lq_H;  // no saturation: one Lq for both terms
  }
  match_by_ = match_by;
  direction_ = direction >= 0.0 ? 1.0 : -1.0;
  first_.size = 0;
  cursor_ = 0;
  origin1_ = 0.0;
  origin2_ = 0.0;
  sums_ = {};
  matched_ = 0;
  ring_sum_ = {};
  ring_count_ = 0;
  ring_next_ = 0;
  sum_omega1_ = sum_omega2_ = sum_iq1_ = sum_iq2_ = sum_id1_ = sum_id2_ = 0.0;
  sum_time1_ = sum_time2_ = 0.0;
  sum_vq_ = sum_iq_ = sum_wid_ = sum_wm_ = sum_gq_ = 0.0;
  sum_vq2_ = sum_wid2_ = sum_wm2_ = sum_gq2_ = 0.0;
  sum_vd_ = sum_id_ = sum_didt_ = sum_wiq_ = sum_gd_ = 0.0;
  sum_lq_sec_ = sum_lq_inc_ = sum_x_lq_sec_ = sum_x_lq_inc_ = sum_xx_ = 0.0;
  sum_emf_ = sum_x_emf_ = 0.0;
  any_clipped_ = false;
  any_limited_ = false;
}

bool PairRecorder::add_first(const PeriodSample& s) {
  if (first_.size >= first_.row.size()) {
    return false;
  }
  if (first_.size == 0) {
    origin1_ = coordinate(s);
  }
  first_.coord[first_.size] = coordinate(s) - origin1_;
  first_.row[first_.size] = {s.i_A.d, s.i_A.q, s.di_dt_A_s.d, s.v_V.d, s.v_V.q, s.dead_time_pattern.d,
                   s.dead_time_pattern.q, s.omega_e_rad_s, s.omega_m_rad_s, 0.0};
  ++first_.size;
  sum_time1_ += s.time_s;
  sum_omega1_ += s.omega_e_rad_s;
  sum_iq1_ += s.i_A.q;
  sum_id1_ += s.i_A.d;
  any_clipped_ = any_clipped_ || s.modulation_clipped;
  any_limited_ = any_limited_ || s.voltage_limited;
  return true;
}

void PairRecorder::begin_second(double origin) {
  origin2_ = origin;
  // Recording 1 is complete: its extent decides the blocks (kFitBlocks in the header), whole
  // turns per block where it holds kFitBlocks turns.
  sums_.used = match_by_ == MatchBy::kAngle && first_extent() >= kFitBlocks * kTwoPi ? kFitBlocks : kFitBlocksShort;
  cursor_ = 0;
  ring_sum_ = {};
  ring_count_ = 0;
  ring_next_ = 0;
}

double PairRecorder::add_second(const PeriodSample& s) {
  // Every sample of either recording marks the pair, matched or not (as add_first).
  any_clipped_ = any_clipped_ || s.modulation_clipped;
  any_limited_ = any_limited_ || s.voltage_limited;
  const double phi = coordinate(s) - origin2_;
  const double extent = first_extent();
  if (first_.size < 4 || phi < 0.0 || phi > extent) {
    return phi;
  }
  // Recording 1's samples are in increasing coordinate; advance the cursor to the pair that
  // brackets phi.
  while (cursor_ + 2 < first_.size && first_.coord[cursor_ + 1] < phi) {
    ++cursor_;
  }
  // Four samples around the bracket [cursor, cursor + 1], shifted inwards at the ends.
  const std::size_t first = std::min(cursor_ > 0 ? cursor_ - 1 : 0, first_.size >= 4 ? first_.size - 4 : 0);
  if (first_.size < 4) {
    return phi;
  }
  const std::array<double, 4> c4{first_.coord[first], first_.coord[first + 1], first_.coord[first + 2], first_.coord[first + 3]};
  for (std::size_t j = 1; j < 4; ++j) {
    if (!(c4[j] - c4[j - 1] > 1e-12)) {
      return phi;  // repeated coordinates (a stalled rotor): no sensible interpolation here
    }
  }
  // Recording 1 at phi: every channel the same weighted sum of the four rows.
  const Weights w = lagrange_weights(c4, phi);
  const Row& r0 = first_.row[first];
  const Row& r1 = first_.row[first + 1];
  const Row& r2 = first_.row[first + 2];
  const Row& r3 = first_.row[first + 3];
  Row r;
  for (std::size_t k = 0; k < kChannels; ++k) {
    r[k] = 0.0 + w.w[0] * r0[k] + w.w[1] * r1[k] + w.w[2] * r2[k] + w.w[3] * r3[k];
  }

  // Eqs. 37 / 43, recording 1 minus recording 2 at the same angle:
  // dVd + d(w psi_q) = Rs dId + Vx dGd + Ld d(dId/dt), with d(w psi_q) = Lq iq dw +
  // Lq_inc w diq (the secant and the incremental inductance; equal without saturation), and
  // the EMF's share c dw that an angle error puts on the measured d axis (emf_d_Wb).
  const double y = (r[kVd] - s.v_V.d) - config_.emf_d_Wb * (r[kOmegaE] - s.omega_e_rad_s) +
                   config_.lq_H * 0.5 * (r[kIq] + s.i_A.q) * (r[kOmegaE] - s.omega_e_rad_s) +
                   config_.lq_incremental_H * 0.5 * (r[kOmegaE] + s.omega_e_rad_s) * (r[kIq] - s.i_A.q) -
                   config_.ld_H * (r[kDidDt] - s.di_dt_A_s.d);
  const std::array<double, kRegressors + 1> raw{r[kId] - s.i_A.d, r[kGd] - s.dead_time_pattern.d,
                                                r[kDidDt] - s.di_dt_A_s.d, y};
  // Moving average over the last filter_length matched samples (the same on every channel).
  const int length = std::clamp(config_.filter_length, 1, kMaxFilter);
  auto& slot = ring_[static_cast<std::size_t>(ring_next_)];
  if (ring_count_ >= length) {
    for (std::size_t c = 0; c <= kRegressors; ++c) {
      ring_sum_[c] -= slot[c];
    }
  }
  for (std::size_t c = 0; c <= kRegressors; ++c) {
    slot[c] = raw[c];
    ring_sum_[c] += raw[c];
  }

  ring_next_ = ring_next_ + 1 >= length ? 0 : ring_next_ + 1;
  ring_count_ = std::min(ring_count_ + 1, length);
  ++matched_;
  if (ring_count_ == length) {
    const double inv = 1.0 / length;
    const std::array<double, kRegressors> x{ring_sum_[0] * inv, ring_sum_[1] * inv, ring_sum_[2] * inv};
    const int blocks = sums_.used;  // begin_second
    const int block = std::clamp(static_cast<int>(phi / std::max(extent, 1e-12) * blocks), 0, blocks - 1);
    sums_.blocks[static_cast<std::size_t>(block)].add(x, ring_sum_[kRegressors] * inv);
  }

  sum_time2_ += s.time_s;
  sum_omega2_ += s.omega_e_rad_s;
  sum_iq2_ += s.i_A.q;
  sum_id2_ += s.i_A.d;
  const double wid2 = s.omega_e_rad_s * s.i_A.d;
  sum_vq_ += 0.5 * (r[kVq] + s.v_V.q);
  sum_iq_ += 0.5 * (r[kIq] + s.i_A.q);
  sum_wid_ += 0.5 * (r[kOmegaE] * r[kId] + wid2);
  sum_wm_ += 0.5 * (r[kOmegaM] + s.omega_m_rad_s);
  sum_gq_ += 0.5 * (r[kGq] + s.dead_time_pattern.q);
  // Recording 2's own q-axis sums: with the means above they give the recordings' difference.
  sum_vq2_ += s.v_V.q;
  sum_wid2_ += wid2;
  sum_wm2_ += s.omega_m_rad_s;
  sum_gq2_ += s.dead_time_pattern.q;
  sum_vd_ += 0.5 * (r[kVd] + s.v_V.d);
  sum_id_ += 0.5 * (r[kId] + s.i_A.d);
  sum_didt_ += 0.5 * (r[kDidDt] + s.di_dt_A_s.d);
  sum_wiq_ += 0.5 * (r[kOmegaE] * r[kIq] + s.omega_e_rad_s * s.i_A.q);
  sum_gd_ += 0.5 * (r[kGd] + s.dead_time_pattern.d);
  // y's Lq terms per henry (PairConditions::lq_secant_mean_V_H), and weighted by dId.
  const double lq_sec = 0.5 * (r[kIq] + s.i_A.q) * (r[kOmegaE] - s.omega_e_rad_s);
  const double lq_inc = 0.5 * (r[kOmegaE] + s.omega_e_rad_s) * (r[kIq] - s.i_A.q);
  sum_lq_sec_ += lq_sec;
  sum_lq_inc_ += lq_inc;
  sum_x_lq_sec_ += raw[kRegRs] * lq_sec;
  sum_x_lq_inc_ += raw[kRegRs] * lq_inc;
  sum_xx_ += raw[kRegRs] * raw[kRegRs];
  const double emf = s.omega_e_rad_s - r[kOmegaE];  // y per unit of c
  sum_emf_ += emf;
  sum_x_emf_ += raw[kRegRs] * emf;
  return phi;
}

PairConditions PairRecorder::conditions() const {
  PairConditions c;
  c.samples = matched_;
  c.any_modulation_clipped = any_clipped_;
  c.any_voltage_limited = any_limited_;
  if (first_.size > 0) {
    const auto n1 = static_cast<double>(first_.size);
    c.omega_e_mean_1_rad_s = sum_omega1_ / n1;
    c.iq_mean_1_A = sum_iq1_ / n1;
    c.id_mean_1_A = sum_id1_ / n1;
  }
  if (matched_ > 0) {
    const auto m = static_cast<double>(matched_);
    c.omega_e_mean_2_rad_s = sum_omega2_ / m;
    c.iq_mean_2_A = sum_iq2_ / m;
    c.id_mean_2_A = sum_id2_ / m;
    const double t1 = sum_time1_ / static_cast<double>(std::max<std::size_t>(first_.size, 1));
    const double t2 = sum_time2_ / m;
    const double di = c.id_mean_1_A - c.id_mean_2_A;
    c.time_1_s = t1;
    c.time_2_s = t2;
    // Midway where the levels' difference is too small to weigh the times (no pair is accepted
    // with so little signal; the guard keeps the division finite).
    c.rs_time_s = std::abs(di) > 1e-3 * std::max({std::abs(c.id_mean_1_A), std::abs(c.id_mean_2_A), 1.0})
                      ? (t1 * c.id_mean_1_A - t2 * c.id_mean_2_A) / di
                      : 0.5 * (t1 + t2);
    c.vq_mean_V = sum_vq_ / m;
    c.iq_mean_A = sum_iq_ / m;
    c.omega_e_id_mean_A_rad_s = sum_wid_ / m;
    c.omega_m_mean_rad_s = sum_wm_ / m;
    c.gq_mean = sum_gq_ / m;
    // Recording 1 minus recording 2 at the same angles: 2 (mean - recording 2).
    c.dvq_V = 2.0 * (sum_vq_ - sum_vq2_) / m;
    c.diq_A = 2.0 * (sum_iq_ - sum_iq2_) / m;
    c.domega_e_id_A_rad_s = 2.0 * (sum_wid_ - sum_wid2_) / m;
    c.domega_m_rad_s = 2.0 * (sum_wm_ - sum_wm2_) / m;
    c.dgq = 2.0 * (sum_gq_ - sum_gq2_) / m;
    c.vd_mean_V = sum_vd_ / m;
    c.id_mean_A = sum_id_ / m;
    c.did_dt_mean_A_s = sum_didt_ / m;
    c.omega_e_iq_mean_A_rad_s = sum_wiq_ / m;
    c.gd_mean = sum_gd_ / m;
    c.lq_secant_mean_V_H = sum_lq_sec_ / m;
    c.lq_incremental_mean_V_H = sum_lq_inc_ / m;
    c.lq_secant_x_sum_A_V_H = sum_x_lq_sec_;
    c.lq_incremental_x_sum_A_V_H = sum_x_lq_inc_;
    c.emf_mean_V_Wb = sum_emf_ / m;
    c.emf_x_sum_A_V_Wb = sum_x_emf_;
    c.x_sq_sum_A2 = sum_xx_;
  }
  return c;
}

}  // namespace pmsm::core
