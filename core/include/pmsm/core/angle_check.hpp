// The rotor angle's offset, checked at commissioning: d-axis current levels held at a steady
// speed, and the torque-producing current the drive needs at each.
//
// A drive whose angle is off the rotor's by delta (an encoder offset commissioned a degree or
// two off, `sensors.encoder_offset_rad`) puts part of every "d-axis" current on the true q
// axis: F sin(delta) of torque-producing current. Every injection then makes torque (0.9 Nm
// per degree electrical on the reference, F = 35 A), the speed loop answers it between a
// pair's recordings, and the pairs are rejected for the speed change or read the answer as
// resistance. Measured on the reference heat-up (docs/estimator.md section 6.1): 0.5 degree
// made the calibration refuse its Rs0 as uncertain (Vx never learned), 2 degrees made it time
// out and the run read its model alone.
//
// The check holds the controller-frame d current at +L, -L, +L over the motoring point, each
// level for settle_s and then averaged over whole electrical turns. In each level's average
// the mechanics balance (Eq. 10 with the reluctance torque):
//
//   3/2 p iq_r (psi + (Ld - Lq) id_r)  =  T_load(w)  +  J dw/dt
//
// where (id_r, iq_r) is the current in the rotor's frame, the controller's (id', iq') turned
// back by delta: id_r = id' cos(delta) + iq' sin(delta), iq_r = iq' cos(delta) - id' sin(delta).
// The load is the same at the same speed, so the levels' difference solves for delta: with
// Ld = Lq and the speed settled, tan(delta) = d iq' / d id', the q current the speed loop adds
// to hold the speed against the level's torque; J dw/dt (the speed's slope over each average,
// the commissioned inertia) covers a loop still settling, the reluctance term a salient motor.
// The two +L levels either side of -L cancel a load or speed drift linear in time; their
// disagreement is the check's (noise) error bar, and a check whose error bar is too wide is void.
//
// The result is the correction to add to the controller's electrical angle. Pure and
// allocation-free; the torque balance is solved in the three periods after the last level
// (one Newton solve each), so that no step does more; the outcome is then decided, and the check
// waits settle_s at zero d current (in the corrected frame) before it ends.
#pragma once

#include <array>
#include <cstdint>

namespace pmsm::core {

struct AngleCheckConfig {
  bool enabled = true;
  double level_A = 25.0;                 // the levels' magnitude (the loader: half the calibration's F)
  double settle_s = 0.1;                 // after each level change (the loader: six speed-loop time constants)
  double average_s = 0.04;               // each level's average, rounded to whole electrical turns
  double min_speed_rad_s = 30.0;         // electrical: below it not checked (friction holds a rotor at rest)
  double max_speed_change_rad_s = 20.0;  // electrical, plus 10 % of the speed: a moving operating point voids it
  double max_offset_rad = 0.35;          // a larger offset (20 degrees electrical) is refused, not corrected
  double max_std_rad = 0.0087;           // the two +L levels disagree by more (0.5 degree): void
  // A measured offset is corrected only beyond three times its error bar (the levels'
  // disagreement and the saliency model's, combined) and beyond this floor; inside, the angle in
  // use stands: correcting it would add the check's own error (docs/estimator.md section 6.1).
  double min_correction_rad = 0.0017;    // 0.1 degree electrical
  // The PLL speed's noise from the encoder's rounding, RMS per sample (mechanical rad/s;
  // DriveConfig::derive_from_motor from the tracker's settings): what the speed's slope over
  // each level, and with it J dw/dt, cannot be measured better than (AngleCheckResult::
  // speed_std_rad). 0: not counted.
  double speed_noise_rad_s = 0.0;
};

// The controller's motor model the torque balance needs.
struct AngleCheckMotor {
  double flux_linkage_Wb = 0.0;
  double ld_minus_lq_H = 0.0;
  int pole_pairs = 3;
  double inertia_kg_m2 = 0.0;
  // The commissioned Ld - Lq's uncertainty: times the levels' mean q current (the friction's at
  // no load) over psi, what the reluctance term can move the offset by (its error bar).
  double saliency_std_H = 0.0;
};

enum class AngleCheckOutcome : std::uint8_t {
  kNone,            // not run (or still running)
  kMeasured,        // the correction is in offset_rad (applied when at least min_correction_rad)
  kAborted,         // the drive was disabled or lost its samples during the check
  kNotTurning,      // slower than min_speed_rad_s: a rotor held by friction balances nothing
  kNoSpeedLoop,     // the drive is not in speed control: nothing holds the speed against the levels
  kSpeedChanged,    // the levels' mean speeds spread beyond max_speed_change_rad_s + 10 %
  kVoltageLimited,  // a level's command was limited (its current not what was asked)
  kUnsteady,        // the two +L levels disagree beyond max_std_rad: the load moved
  kOutOfRange,      // |offset| above max_offset_rad: a commissioning error to fix, not to correct
  kImplausible,     // a non-finite solve, or levels that did not separate
};

[[nodiscard]] const char* to_string(AngleCheckOutcome outcome);

struct AngleCheckResult {
  AngleCheckOutcome outcome = AngleCheckOutcome::kNone;
  double offset_rad = 0.0;      // add to the controller's electrical angle (kMeasured, kOutOfRange)
  double offset_std_rad = 0.0;  // from the two +L levels' disagreement (the noise, a drift; one degree of freedom)
  double model_std_rad = 0.0;   // what the commissioned saliency's uncertainty can move it by
  // An empirical floor under offset_std_rad, whose one degree of freedom can read far below the
  // check's scatter: the levels' J dw/dt slopes' uncertainty as if the PLL's speed carried
  // AngleCheckConfig::speed_noise_rad_s of white noise (angle_check.cpp says what it misses).
  double speed_std_rad = 0.0;
  double d_iq_A = 0.0;          // the q current the levels moved (+L minus -L), diagnostics
  double d_id_A = 0.0;          // the d current they moved
};

class AngleCheck {
 public:
  static constexpr int kLevels = 3;  // +L, -L, +L
  static constexpr double kMaxSpeedChangeFraction = 0.1;  // of the speed, on top of max_speed_change_rad_s

  AngleCheck() = default;

  void start(const AngleCheckConfig& config, const AngleCheckMotor& motor, double period_s);
  // Ends a check in progress as kAborted; once its outcome is decided, only the wait after it.
  void abort();
  // Started, before its first step (its first level not yet applied).
  [[nodiscard]] bool starting() const { return stage_ == Stage::kSettle && level_ == 0 && elapsed_s_ == 0.0; }
  // Ends the check now with this outcome, before or during its levels (kVoltageLimited: the
  // drive in field weakening, where a level on top of the held d current would hand the machine
  // to its EMF, or a level's command held on the voltage limit).
  void stop(AngleCheckOutcome outcome);
  // Running: its levels, its solves, or the wait at zero d current after its outcome.
  [[nodiscard]] bool active() const { return stage_ != Stage::kIdle; }
  // Its outcome is decided (result() holds it) and it only waits for the drive to settle.
  [[nodiscard]] bool decided() const { return stage_ == Stage::kSettleOut; }
  // The d-axis current to add to the motoring reference this period (0 when not active).
  [[nodiscard]] double id_ref_A() const;

  // One period: the measured current in the controller's frame, the mechanical and
  // electrical speeds, and whether the command was limited. Returns true in the period the
  // check's outcome is decided, whatever it is (a disabled drive or a non-finite input aborts
  // it while it measures); after a solved outcome it stays active for settle_s at zero d
  // current (decided()), and a stop then only ends that wait.
  // `speed_controlled`: the speed loop sets the torque (a drive in torque control lets the
  // levels' torque run the speed away: the check ends, kNoSpeedLoop, and is not started again).
  bool step(bool enabled, bool speed_controlled, double id_A, double iq_A, double omega_m_rad_s, double omega_e_rad_s,
            bool voltage_limited = false);

  [[nodiscard]] const AngleCheckResult& result() const { return result_; }

 private:
  enum class Stage : std::uint8_t { kIdle, kSettle, kAverage, kSolve, kSettleOut };
  void finish(AngleCheckOutcome outcome);
  void finish_level();
  void conclude();
  void solve_step();
  // The torque balance's residual at offset delta: the +L levels' torque (weight_first on the
  // first, the rest on the third) minus the -L level's, each less its J dw/dt (N m).
  [[nodiscard]] double imbalance_Nm(double delta_rad, double weight_first) const;
  [[nodiscard]] double imbalance_slope_Nm_per_rad(double delta_rad, double weight_first) const;  // d imbalance / d delta
  // The delta that balances them; false when the solve does not converge to a finite value.
  [[nodiscard]] bool solve(double weight_first, double* delta_rad) const;

  AngleCheckConfig config_{};
  AngleCheckMotor motor_{};
  double period_s_ = 1e-4;
  Stage stage_ = Stage::kIdle;
  int level_ = 0;
  double elapsed_s_ = 0.0;
  double angle_rad_ = 0.0;
  double target_angle_rad_ = 0.0;
  // Per-level sums: the currents, and the speed against time for its slope.
  int count_ = 0;
  double sum_id_ = 0.0;
  double sum_iq_ = 0.0;
  double sum_t_ = 0.0;
  double sum_w_ = 0.0;
  double sum_tw_ = 0.0;
  double sum_tt_ = 0.0;
  double sum_we_ = 0.0;
  std::array<double, kLevels> mean_id_{};
  std::array<double, kLevels> mean_iq_{};
  std::array<double, kLevels> accel_{};      // mechanical rad/s^2
  std::array<double, kLevels> time_spread_s2_{};  // sum of (t - mean t)^2 over the level's average
  std::array<double, kLevels> speed_e_{};    // electrical rad/s
  int solve_index_ = 0;
  bool speed_steady_ = true;   // the levels' mean speeds within the limit
  AngleCheckOutcome pending_outcome_ = AngleCheckOutcome::kNone;  // reported when the drive has settled
  std::array<double, 3> solved_{};
  AngleCheckResult result_{};
};

}  // namespace pmsm::core
