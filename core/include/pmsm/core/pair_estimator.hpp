// Separation of the injected voltage from the motoring voltage (Section X) and the
// resistance fit that follows it.
//
// Two recordings of the rotor-frame variables (idr, iqr, vdr, vqr, w, wm) are taken over the
// same arc of rotor angle, dTheta apart (2 pi electrical, or 2 pi p for mechanical
// harmonics). Recording 1 is stored; every sample of recording 2 is matched to recording 1 at
// the same relative rotor angle (not time: linear interpolation between the two neighbouring
// samples of recording 1), and the difference enters a least-squares fit at once, so the
// end of a recording costs no more than any other period.
//
// The fit on the d-axis, from Eqs. 37 and 43 (unipolar / bipolar: the bipolar difference
// simply holds twice the injected voltage and current), with Eq. 3's inductive term taken
// to the left with the commissioned Ld0:
//
//   dVd + Lq d(w iq) - Ld0 d(dId/dt)  =  Rs dId  +  Vx dGd  +  (Ld - Ld0) d(dId/dt)
//
// with d(.) = recording 1 minus recording 2 at the same angle. The EMF harmonics kd(theta)
// cancel because the samples are matched by angle. The other two regressors are this
// project's additions, each optional:
//  - Vx dGd: the inverter's dead-time and device-drop voltage. It opposes the sign pattern
//    of the three phase currents, Gd being the d-axis projection of that pattern; it changes
//    between the recordings because the injection turns the current vector, and what is left
//    of it after compensation is as large as the resistive signal itself (DESIGN section 5),
//    so it is fitted rather than ignored. The voltage the fit sees is the controller's
//    command *including* the compensation it applied (from the reference current), and Vx is
//    the bridge's whole per-phase error voltage (from the measured current): modelling only
//    the residual would assume the compensation's signs equal the true currents' signs, which
//    fails near every zero crossing in a way that differs between the recordings.
//  - Ld d(dId/dt): the inductive voltage of a current that changes within the recording
//    (fixed-angle injection, Eq. 14). This makes the fit the least-squares form of Eq. 22:
//    the separated voltage resolved along the resistive (Id) and inductive (dId/dt)
//    directions, over all matched samples rather than one.
//
// The q-axis of the same recordings gives the EMF constant once Rs is known (Eq. 34/40
// averaged over both recordings), hence the magnet temperature.
#pragma once

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <utility>
#include <vector>

#include "pmsm/core/transforms.hpp"

namespace pmsm::core {

// One control period as the estimator sees it: averages over the period during which the
// voltage command was applied.
struct PeriodSample {
  double time_s = 0.0;
  double theta_e_rad = 0.0;     // unwrapped electrical angle at the middle of the period
  double omega_e_rad_s = 0.0;   // the period's mean: the encoder's advance over it / period
  double omega_m_rad_s = 0.0;   // the speed observer's (mechanical)
  Dq i_A{};                     // measured current, average over the period
  Dq di_dt_A_s{};               // its rate of change over the period
  Dq v_V{};                     // voltage command applied during the period, in the rotor's frame
  Dq dead_time_pattern{};       // dq projection of the phase-current sign pattern (see above)
  bool voltage_limited = false; // the applied command had been on the current loop's voltage limit
  // The bridge may not have applied the command: a phase's duty clipped at 0 or 1, or closer to
  // a rail than 1.5 dead times (pulse_lost(), modulation.hpp), so the voltage the machine saw
  // may not be the recorded one. On the loop's limit alone (voltage_limited) the command stays
  // inside the linear modulation range and is applied as recorded.
  bool modulation_clipped = false;
};

enum class MatchBy : std::uint8_t { kAngle, kTime };

// The regressors of the d-axis fit, always accumulated; a fit chooses which to use.
enum Regressor : int { kRegRs = 0, kRegVx = 1, kRegLd = 2, kRegressors = 3 };

// Normal-equation sums of the d-axis fit, additive over samples, blocks and pairs.
struct FitSums {
  std::array<std::array<double, kRegressors>, kRegressors> xtx{};
  std::array<double, kRegressors> xty{};
  double yty = 0.0;
  double n = 0.0;
  std::array<double, kRegressors> sum_x{};  // for the means over whole turns
  double sum_y = 0.0;

  void add(const std::array<double, kRegressors>& x, double y);
  void add(const FitSums& other, double sign = 1.0);
};

// Jackknife blocks (docs/estimator.md section 3, "How many blocks"): a recording of at least
// kFitBlocks whole electrical turns is cut into kFitBlocks, each a turn or more, so that the
// variance is estimated with 15 degrees of freedom instead of 7; a shorter one (and a
// time-based one) into kFitBlocksShort, whose blocks are parts of a turn: there the pattern
// within a turn (EMF harmonics, the bridge's six steps), which cancels over whole turns, would
// differ between shorter blocks and read as noise.
inline constexpr int kFitBlocks = 16;
inline constexpr int kFitBlocksShort = 8;

// Sums of one or more pairs, kept per block so the jackknife can leave blocks out.
struct BlockedSums {
  std::array<FitSums, kFitBlocks> blocks{};
  // The blocks the jackknife leaves out in turn, the first `used`: set by the recorder, the
  // largest of the pairs summed (add); 0, not set (sums filled by hand), counts as kFitBlocks.
  int used = 0;
  void add(const BlockedSums& other);
  [[nodiscard]] FitSums total() const;
};

struct FitOptions {
  bool fit_vx = true;           // estimate Vx; otherwise hold it at fixed_vx_V
  double fixed_vx_V = 0.0;
  bool fit_ld = false;          // include the Ld d(dId/dt) regressor
};

struct FitResult {
  bool valid = false;           // enough samples, well conditioned, jackknife complete
  double rs_ohm = 0.0;
  double vx_V = 0.0;            // fitted, or the fixed value
  double ld_H = 0.0;
  // Jackknife covariance of (Rs, Vx); var_vx and cov are 0 when Vx is held fixed.
  double var_rs = 0.0;
  double var_vx = 0.0;
  double cov_rs_vx = 0.0;
  double residual_rms_V = 0.0;
  double signal_rms_A = 0.0;    // RMS of dId
  double condition = 0.0;       // reciprocal condition of the scaled normal matrix
  double samples = 0.0;
  // Sensitivity of the fixed-Vx Rs to the assumed Vx: dRs/dVx = -sum(dId dGd) / sum(dId^2).
  double drs_dvx = 0.0;
  // How much of dGd the resistive regressor dId cannot explain, 1 - rho^2 with rho their
  // (uncentred) correlation: near 0 the two are collinear and Vx is not identifiable from
  // these samples, whatever the jackknife says (the split is then decided by model error).
  double vx_identifiability = 0.0;
};

// Least squares on blocked sums, with the jackknife over blocks for the covariance.
[[nodiscard]] FitResult solve_fit(const BlockedSums& sums, const FitOptions& options);

// Rs and Vx from the means of several pairs over their whole recordings (whole electrical
// turns, or the whole pulse): mean(y) = Rs mean(dId) + Vx mean(dGd) per pair, each weighted
// by the noise its own regression shows. Anything periodic within a turn (EMF harmonics and what they do to
// the currents, the speed and the interpolation) averages out of the means, so this is how
// Vx is learned: across levels, from the change of mean(dGd) / mean(dId) with F. The
// sample-by-sample fit can also separate the two from the dead-time pattern's six-step
// content within a turn, but at speed that content is exactly where harmonic residues sit.
struct MeansFit {
  bool valid = false;
  double rs_ohm = 0.0;
  double vx_V = 0.0;
  double var_rs = 0.0;
  double var_vx = 0.0;
  double cov_rs_vx = 0.0;
  double identifiability = 0.0;  // 1 - rho^2 of the weighted design
  // ... and of the design alone, the levels' geometry without the noise weights. With two
  // pairs (the usual event) the fit passes through both means whatever their weights, so a
  // model error in either moves Vx by what this allows (InjectionScheduler::finish_event
  // takes it at rest).
  double design_identifiability = 0.0;
  double drs_dvx = 0.0;          // fixed-Vx form: how the Rs moves with the assumed Vx
};
[[nodiscard]] MeansFit solve_means_fit(const BlockedSums* pairs, int count, bool fit_ld);

// One pair's whole-recording means, mean(y) = Rs mean(dId) + Vx mean(dGd), with the weight
// of the noise of its mean(y): what the pair's own regression (Vx held, the inductive term
// fitted) says about its Rs, times mean(dId). Empty when the pair's own fit fails. Each costs
// one regression (as much as a pair's own fit), so a drive computes them one per control
// period and passes them to the overloads below (the scheduler does).
struct PairMeans {
  double x_rs = 0.0;  // mean(dId)
  double x_vx = 0.0;  // mean(dGd)
  double y = 0.0;
  double w = 0.0;
};
[[nodiscard]] std::optional<PairMeans> pair_means(const BlockedSums& pair, bool fit_ld);
[[nodiscard]] MeansFit solve_means_fit(const std::optional<PairMeans>* means, int count);

// The same means with Vx held at a known value (one level, or levels that do not reverse the
// current): Rs alone. For flat (fixed-magnitude) pulses this, not the sample-by-sample fit,
// gives the published Rs: the current loop answers the current sensor's noise with voltage
// (Kp = wc L, about 80 times Rs), so within a recording the measured dId and the commanded
// voltage share that noise with opposite signs and a least-squares slope over samples is
// pulled low (closed-loop errors-in-variables); the sign pattern computed from noisy currents
// near their zero crossings adds to it. The means over whole recordings carry neither. On the
// reference profile at 94 rad/s and 60 Nm the sample fit read 0.8 % low relative to the
// no-load calibration (0.4 % without sensor noise), the means 0.2 % high (docs/estimator.md).
[[nodiscard]] MeansFit solve_means_fit_fixed_vx(const BlockedSums* pairs, int count, bool fit_ld, double vx_V);
[[nodiscard]] MeansFit solve_means_fit_fixed_vx(const std::optional<PairMeans>* means, int count, double vx_V);

struct PairFitConfig {
  double lq_H = 5.5e-3;         // the controller's Lq, for the Eq. 37 correction term
  // On a saturating machine the q-axis flux is psi_q(iq) = Lq iq with a secant Lq that falls
  // with |iq|: d(w psi_q) = Lq iq dw + Lq_inc w diq, where the incremental Lq_inc =
  // d psi_q / d iq is below the secant. 0: the same as lq_H (no saturation).
  double lq_incremental_H = 0.0;
  // The controller's Ld: Eq. 3's Ld dId/dt is moved to the left with it, so that a current
  // still settling during a recording does not pose as resistance (the means fit has no
  // inductive term; the sample fit's Ld regressor then fits only the residue of Ld's error).
  double ld_H = 5.5e-3;
  // The d axis's share of the magnet's EMF that a rotor-angle error delta leaves in the
  // measured frame, c = psi delta: <vd> holds c w, and y the difference c dw between the
  // recordings (learned with Lq: InjectionConfig::lq_angle_std_rad). 0: none.
  double emf_d_Wb = 0.0;
  // Moving-average length (periods) applied alike to y and every regressor before the fit.
  // The relation is linear with constant coefficients, so filtering both sides keeps it
  // exact, while the noise of the two-sample derivative d(dId/dt) falls by this factor: with
  // a deterministic inductive signal (fixed-angle pulses) the fitted Ld would otherwise carry
  // sensor noise of tens of volts into the fit.
  int filter_length = 8;
};

// Operating conditions of a pair, for the guards of Section X and the EMF constant.
struct PairConditions {
  std::size_t samples = 0;
  double omega_e_mean_1_rad_s = 0.0;
  double omega_e_mean_2_rad_s = 0.0;
  double iq_mean_1_A = 0.0;
  double iq_mean_2_A = 0.0;
  double id_mean_1_A = 0.0;
  double id_mean_2_A = 0.0;
  // The time the pair's Rs belongs to on a winding that warms during the pair. The pair
  // measures Rs(t1) id1 - Rs(t2) id2 (recordings' mean times and d-axis currents); with Rs
  // linear in time that is Rs(t) (id1 - id2) at t = (t1 id1 - t2 id2) / (id1 - id2): midway for
  // a bipolar pair (id2 = -id1), recording 2's time for a unipolar one (id1 = 0), beyond
  // recording 2 for a field-weakening one (both levels negative; with levels -0.3 F and -F,
  // 0.43 of the recordings' spacing after recording 2).
  double rs_time_s = 0.0;
  double time_1_s = 0.0;  // the recordings' mean times (t1, t2 above)
  double time_2_s = 0.0;
  // A sample whose command the bridge may not have applied (PeriodSample::modulation_clipped):
  // the pair is rejected (PairOutcome::kRejectedVoltageSaturation).
  bool any_modulation_clipped = false;
  // A sample of either recording on the voltage limit (PeriodSample::voltage_limited). It does
  // not reject the pair (the command was applied, and the fit takes the measured currents;
  // docs/estimator.md section 2): only reported, how often the budget's pulses meet the limit.
  bool any_voltage_limited = false;
  // q-axis means over both recordings at the same angles.
  double vq_mean_V = 0.0;
  double iq_mean_A = 0.0;
  double omega_e_id_mean_A_rad_s = 0.0;  // mean of w * id
  double omega_m_mean_rad_s = 0.0;
  double gq_mean = 0.0;
  // The same q-axis quantities, recording 1 minus recording 2 at the same angles: Eq. 3's
  // q axis differenced, dvq = Rs diq + Ld d(w id) + Ke dwm + Vx dGq, where d(w id) is the
  // levels' difference times the speed, so the pair measures Ld too (magnet temperature).
  double dvq_V = 0.0;
  double diq_A = 0.0;
  double domega_e_id_A_rad_s = 0.0;
  double domega_m_rad_s = 0.0;
  double dgq = 0.0;
  // d-axis means over both recordings at the same angles, for the q-axis inductance: over
  // whole turns Eq. 3 leaves <vd> = Rs <id> + Ld <dId/dt> - Lq <w iq> + Vx <Gd>.
  double vd_mean_V = 0.0;
  double id_mean_A = 0.0;
  double did_dt_mean_A_s = 0.0;
  double omega_e_iq_mean_A_rad_s = 0.0;  // mean of w * iq
  double gd_mean = 0.0;
  // How y depends on the Lq the pair was fitted with (Eq. 37's term, recording 1 minus 2 at
  // the same angle): y moves by S_sec dLq_sec + S_inc dLq_inc per sample, with S_sec =
  // mean(iq) dw and S_inc = mean(w) diq. Their means over the matched samples (volts per
  // henry), for the means of fixed-magnitude pairs, and their sums weighted by the resistive
  // regressor dId with that regressor's sum of squares, for the sample fit (a turning vector,
  // fixed-angle or DC, has a mean dId near zero).
  double lq_secant_mean_V_H = 0.0;
  double lq_incremental_mean_V_H = 0.0;
  double lq_secant_x_sum_A_V_H = 0.0;
  double lq_incremental_x_sum_A_V_H = 0.0;
  // The same for the angle error's EMF share (PairFitConfig::emf_d_Wb): y moves by -dw dc.
  double emf_mean_V_Wb = 0.0;
  double emf_x_sum_A_V_Wb = 0.0;
  double x_sq_sum_A2 = 0.0;
};

// Recording of one pair: add samples to recording 1, close it, then add samples of recording
// 2; each is matched and accumulated immediately.
class PairRecorder {
 public:
  explicit PairRecorder(std::size_t capacity);

  void start(const PairFitConfig& config, MatchBy match_by, double direction);
  // Recording 1. Returns false when full (the sample is dropped).
  bool add_first(const PeriodSample& s);
  // The extent of recording 1, in the matching coordinate (angle from its first sample, or
  // time); recording 2 must cover the same.
  [[nodiscard]] double first_extent() const { return first_.size == 0 ? 0.0 : first_.coord[first_.size - 1]; }
  [[nodiscard]] std::size_t first_size() const { return first_.size; }
  // Start of recording 1 in the matching coordinate (absolute angle or time).
  [[nodiscard]] double first_origin() const { return origin1_; }
  // Recording 2: origin is the matching coordinate of recording 1's origin plus dTheta.
  void begin_second(double origin);
  // Adds a sample of recording 2 (matched and accumulated); returns its relative coordinate.
  double add_second(const PeriodSample& s);
  [[nodiscard]] bool second_complete(const PeriodSample& s) const {
    return coordinate(s) - origin2_ >= first_extent();
  }

  [[nodiscard]] const BlockedSums& sums() const { return sums_; }
  [[nodiscard]] PairConditions conditions() const;

  // Coordinate of a sample in the matching space (direction-signed angle, or time). Inline,
  // with the two above: the scheduler asks every period of a pair.
  [[nodiscard]] double coordinate(const PeriodSample& s) const {
    return match_by_ == MatchBy::kAngle ? angle_coordinate(s.theta_e_rad) : s.time_s;
  }
  // The coordinate of an angle when matching by angle (before a sample is built for it).
  [[nodiscard]] double angle_coordinate(double theta_e_rad) const { return direction_ * theta_e_rad; }

 private:
  // Recording 1 as the matching reads it, preallocated at construction (never grows): each
  // sample's coordinate from recording 1's origin, the channels the match needs in one
  // contiguous row (the four-point interpolation combines whole rows, which the compiler
  // vectorises; the last channel is padding so that a row splits into pairs of doubles).
  enum Channel : std::size_t { kId, kIq, kDidDt, kVd, kVq, kGd, kGq, kOmegaE, kOmegaM, kPad, kChannels };
  using Row = std::array<double, kChannels>;
  // A copy-assignment carries only the samples recorded, not the whole capacity: the simulator
  // copies a drive into its twin's buffers at every injection event, and the buffers are sized
  // for the longest pulse (a copy-construction allocates the capacity, once per buffer).
  struct Recording {
    std::vector<double> coord;
    std::vector<Row> row;
    std::size_t size = 0;

    explicit Recording(std::size_t capacity) : coord(capacity), row(capacity) {}
    ~Recording() = default;
    Recording(const Recording& other) : coord(other.coord.size()), row(other.row.size()) {
      copy_recorded(other);
    }
    Recording& operator=(const Recording& other) {
      if (this != &other) {
        if (row.size() != other.row.size()) {
          coord.resize(other.coord.size());
          row.resize(other.row.size());
        }
        copy_recorded(other);
      }
      return *this;
    }
    // A moved-from recording is empty (its buffers went with the move).
    Recording(Recording&& other) noexcept
        : coord(std::move(other.coord)),
          row(std::move(other.row)),
          size(std::exchange(other.size, 0)) {}
    Recording& operator=(Recording&& other) noexcept {
      coord = std::move(other.coord);
      row = std::move(other.row);
      size = std::exchange(other.size, 0);
      return *this;
    }

   private:
    void copy_recorded(const Recording& other) {
      std::copy_n(other.coord.begin(), other.size, coord.begin());
      std::copy_n(other.row.begin(), other.size, row.begin());
      size = other.size;
    }
  };
  Recording first_;
  std::size_t cursor_ = 0;
  PairFitConfig config_{};
  MatchBy match_by_ = MatchBy::kAngle;
  double direction_ = 1.0;
  double origin1_ = 0.0;
  double origin2_ = 0.0;
  BlockedSums sums_{};
  std::size_t matched_ = 0;
  // Moving-average state of the matched differences (y and the regressors).
  static constexpr int kMaxFilter = 32;
  std::array<std::array<double, kRegressors + 1>, kMaxFilter> ring_{};
  std::array<double, kRegressors + 1> ring_sum_{};
  int ring_count_ = 0;
  int ring_next_ = 0;
  double sum_omega1_ = 0.0, sum_omega2_ = 0.0, sum_iq1_ = 0.0, sum_iq2_ = 0.0;
  double sum_id1_ = 0.0, sum_id2_ = 0.0;
  double sum_time1_ = 0.0, sum_time2_ = 0.0;
  double sum_vq_ = 0.0, sum_iq_ = 0.0, sum_wid_ = 0.0, sum_wm_ = 0.0, sum_gq_ = 0.0;
  double sum_vq2_ = 0.0, sum_wid2_ = 0.0, sum_wm2_ = 0.0, sum_gq2_ = 0.0;
  double sum_vd_ = 0.0, sum_id_ = 0.0, sum_didt_ = 0.0, sum_wiq_ = 0.0, sum_gd_ = 0.0;
  double sum_lq_sec_ = 0.0, sum_lq_inc_ = 0.0, sum_x_lq_sec_ = 0.0, sum_x_lq_inc_ = 0.0, sum_xx_ = 0.0;
  double sum_emf_ = 0.0, sum_x_emf_ = 0.0;
  bool any_clipped_ = false;
  bool any_limited_ = false;
};

}  // namespace pmsm::core
