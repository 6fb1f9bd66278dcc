// The bridge's voltage error, measured at commissioning: a d-axis current sweep.
//
// The estimator models the inverter's whole voltage error as Vx G(i), G the dq projection of
// the soft-sign pattern of the three phase currents with a zero-current band b inside which
// the PWM ripple makes the error fade linearly to zero (modulation.hpp, docs/estimator.md §4).
// Vx and b are properties of the bridge, not of the motor, and both were taken on trust: the
// calibration learns Vx only to about +-0.04 V, and b is a key. A band 33 % off the bridge's
// moves every resistance estimate under load by about half a percent (docs/accuracy.md).
//
// The sweep holds a sequence of d-axis current levels of both signs, from well inside the
// band to well outside it, at the operating point the calibration runs at (standstill or a
// steady no-load speed), and averages over each level
//
//   <vd>  =  Rs <id>  +  Vx <Gd(b)>  +  c                    (Eq. 3, d axis, steady level)
//
// where c collects what does not change sign with the level (-w Lq iq of the small no-load
// iq, the mean of the EMF's d-axis harmonics over whole turns). <Gd(b)> is accumulated for a
// fixed grid of candidate bands; the band whose linear fit leaves the least residual wins, and
// a golden-section search between its neighbours (Gd interpolated in the band index) refines
// it. Dead time is odd in the current and saturates, the resistive drop is linear and c is
// even: the three separate. The band is what the estimator uses; the sweep's Vx is reported
// (docs/estimator.md section 4.1 says why it is not the calibration's prior).
//
// Pure and allocation-free: fixed-size accumulators, one candidate-band fit per period after the
// last level (a grid of candidate bands, then a golden-section search between them; no period
// does more than one fit).
#pragma once

#include <array>
#include <cstdint>

#include "pmsm/core/transforms.hpp"

namespace pmsm::core {

struct InverterSweepConfig {
  bool enabled = true;
  double max_current_A = 25.0;      // the largest level (the loader: half the calibration's F)
  double settle_s = 0.005;          // after each level change, before averaging (>10 current-loop time constants)
  double average_s = 0.03;          // averaging per level, rounded to whole electrical turns
  // The sweep is void if the electrical speed moves more than this (plus 5 % of it) between
  // levels: a load change, not the bridge.
  double max_speed_change_rad_s = 20.0;
};

enum class InverterSweepOutcome : std::uint8_t {
  kNone,              // not run (or still running)
  kMeasured,
  kAborted,           // the drive was disabled or lost its samples during the sweep
  kSpeedChanged,      // the operating point moved during the sweep
  kVoltageLimited,    // a level's command was limited (not what the bridge applied)
  kBandAtLimit,       // the best band is at the end of the candidate range: not resolved
  kImplausible,       // Vx <= 0, Rs <= 0, or a singular fit
  kUnresolved,        // the fit's own Vx error bar is not small against Vx: the levels did not
                      // resolve the bridge (a q current that moved under them), not used
};

[[nodiscard]] const char* to_string(InverterSweepOutcome outcome);

struct InverterSweepResult {
  InverterSweepOutcome outcome = InverterSweepOutcome::kNone;
  double vx_V = 0.0;
  double vx_std_V = 0.0;
  double band_A = 0.0;
  double rs_ohm = 0.0;              // the fit's resistance (diagnostic; Rs0 is the calibration's)
  double offset_V = 0.0;            // c
  double residual_rms_V = 0.0;      // of the level means about the best fit
  // The levels were fitted and the figures above are that fit's, whatever the outcome made of
  // it (measured, speed_changed, unresolved, band_at_limit, and implausible after a fit: Vx or
  // Rs <= 0). False where no fit was made (aborted, voltage_limited, a singular fit): the
  // figures are then zero and mean nothing.
  bool fitted = false;
};

class InverterSweep {
 public:
  static constexpr int kLevels = 12;        // six magnitudes, both signs
  static constexpr int kBands = 32;         // candidate bands, log-spaced
  static constexpr double kBandMinFraction = 0.005;  // of max_current_A
  static constexpr double kBandMaxFraction = 0.5;
  // A fit whose Vx standard error exceeds this share of |Vx| resolved no bridge (it comes
  // before the sign test: such a fit's Vx may have either sign). Measured: the suite's 119 sweeps
  // that measured read 0.07-4.6 % (median 0.35 %; the reference 0.3 %); a 6 mOhm traction
  // motor's sweeps that ran into its speed ramp's end, 130 A of q current under the small levels
  // and 10 A under the large ones, read 73-430 % with bands of 1.7-53 A against 4.7 A. A steady
  // q current many bands wide is not always caught: 30-35 A under that motor's levels read 13
  // and 23 A within 3-4 % (docs/accuracy.md, "A sweep that resolved nothing").
  static constexpr double kMaxVxStdFraction = 0.1;

  InverterSweep() = default;

  void start(const InverterSweepConfig& config, double period_s);
  void abort();
  // Started, before its first step (its first level not yet applied).
  [[nodiscard]] bool starting() const { return stage_ == Stage::kSettle && level_ == 0 && elapsed_s_ == 0.0; }
  // Ends the sweep now with this outcome, before or during its levels (kVoltageLimited: the
  // drive in field weakening, or a level's command held on the voltage limit).
  void stop(InverterSweepOutcome outcome);
  [[nodiscard]] bool active() const { return stage_ != Stage::kIdle; }
  // The d-axis current to add to the motoring reference this period (0 when not active).
  [[nodiscard]] double id_ref_A() const;

  // One period. `i_A`: the phase currents measured at its end; `mid`: the rotation at the
  // middle of the period that just ended; `vd_V`, `id_A`: the applied d-axis command and the
  // mean current of that period; `omega_e_rad_s`: electrical speed; `voltage_limited`: that
  // period's command had been limited. Returns true in the period the sweep finished (also
  // when it was void: a disabled drive or a non-finite input aborts it).
  bool step(bool enabled, const Abc& i_A, const Rotation& mid, double vd_V, double id_A, double omega_e_rad_s,
            bool voltage_limited = false);

  [[nodiscard]] const InverterSweepResult& result() const { return result_; }
  [[nodiscard]] double level_A(int level) const;

 private:
  enum class Stage : std::uint8_t { kIdle, kSettle, kAverage, kFit };
  void finish_level();
  struct LevelFit {
    bool valid = false;
    double sse = 0.0;
    double rs_ohm = 0.0;
    double vx_V = 0.0;
    double offset_V = 0.0;
    double vx_var = 0.0;
  };
  static constexpr int kGoldenSteps = 26;  // two periods evaluate the first pair of points
  [[nodiscard]] LevelFit fit_levels(double band_index, int centre) const;
  [[nodiscard]] double band_candidate_A(int k) const;
  void fit_step();
  void conclude();

  InverterSweepConfig config_{};
  double period_s_ = 1e-4;
  Stage stage_ = Stage::kIdle;
  int level_ = 0;
  double elapsed_s_ = 0.0;
  double angle_rad_ = 0.0;          // electrical angle travelled while averaging
  double target_angle_rad_ = 0.0;   // whole turns to average over (0: by time)
  double speed_min_ = 0.0;
  double speed_max_ = 0.0;
  std::array<double, kBands> bands_{};  // the candidate bands, A
  // The pattern is built from phase currents averaged over kSmooth samples centred on each
  // period end: the sensor's noise (0.2 A on the reference drive) rounds the soft-sign's corners
  // and reads the band low (0.65-0.72 A against 0.75 A measured from single samples); a centred
  // average keeps the currents' own ripple (the EMF harmonics move the zero crossings at speed)
  // and shifts the pattern two periods against the voltage, which the level means do not see.
  static constexpr int kSmooth = 5;
  static constexpr int kRing = kSmooth + 1;
  std::array<Abc, kRing> ring_i_{};
  std::array<Rotation, kRing> ring_mid_{};
  int ring_count_ = 0;
  int ring_head_ = 0;               // where the next sample goes
  // Per-level accumulation.
  int count_ = 0;
  double sum_vd_ = 0.0;
  double sum_id_ = 0.0;
  double sum_omega_ = 0.0;
  std::array<double, kBands> sum_gd_{};
  // Level means.
  std::array<double, kLevels> mean_vd_{};
  std::array<double, kLevels> mean_id_{};
  std::array<std::array<double, kBands>, kLevels> mean_gd_{};
  // The fits, one a period: the grid, then a golden-section search between its best's
  // neighbours, then the optimum and its two sides.
  int fit_index_ = 0;
  std::array<double, kBands> grid_sse_{};
  int best_grid_ = 0;
  int centre_ = 1;                  // the interpolation's centre during the search
  double lo_ = 0.0;
  double hi_ = 0.0;
  double x1_ = 0.0;
  double x2_ = 0.0;
  double f1_ = 0.0;
  double f2_ = 0.0;
  std::array<LevelFit, 3> side_{};
  InverterSweepResult result_{};
};

}  // namespace pmsm::core
