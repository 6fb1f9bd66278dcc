// Continuous winding temperature between injections: a two-node thermal model (winding,
// stator/housing, to ambient) driven by the losses the controller can compute, fused with the
// resistance measurements by a Kalman filter. Three more states, the model's errors (the
// copper loss's relative error in the winding, a missing loss in watts in the housing, and the
// cooling path's relative error, which scales the housing's heat to the ambient), let the filter
// learn a model mismatch from the measurements, which keeps the prediction honest between
// measurements and the time-to-limit sensible.
//
// Also here: temperature from resistance (Eq. 1) through the calibration, time-to-limit at
// the present load, and current-limit derating from the upper confidence bound.
#pragma once

#include <array>
#include <cmath>
#include <limits>

#include <Eigen/Core>

namespace pmsm::core {

struct ThermalModelConfig {
  // The controller's model, from the motor's thermal data as commissioned: a two-node
  // simplification of the real machine (rotor lumped into the housing), each value within
  // about 10 % of the Table I motor's network (docs/estimator.md). It need not be exact:
  // the filter's loss-error state and the resistance measurements correct it.
  double winding_capacity_J_K = 2800.0;
  double housing_capacity_J_K = 18000.0;
  double winding_to_housing_K_W = 0.055;
  double housing_to_ambient_K_W = 0.125;
  // A shaft-mounted fan (a self-ventilated machine, IC411): housing_to_ambient_K_W holds at the
  // mechanical speed fan_speed_rad_s, and the path's conductance scales as
  // fan_standstill_share + (1 - fan_standstill_share) (|wm| / fan_speed_rad_s)^fan_exponent:
  // natural convection at rest, forced convection growing with the fan's air flow. 0: no shaft
  // fan (a separately ventilated, water-jacketed or non-ventilated machine): the path does not
  // depend on the speed (housing_cooling_share below).
  double fan_speed_rad_s = 0.0;
  double fan_standstill_share = 0.35;
  double fan_exponent = 0.8;
  // Speed-dependent losses on the housing node, P = k1 |wm| + k2 wm^2: iron loss (hysteresis
  // and eddy currents) and the friction heat that stays in the machine.
  double iron_loss_k1_W_s_rad = 0.6;
  double iron_loss_k2_W_s2_rad2 = 1.0e-3;
  // The winding's conductor for Eq. 1: its inferred zero-resistance temperature (copper
  // 234.5 C, aluminium 225 C; machine_equations.hpp).
  double conductor_inferred_zero_C = 234.5;
  // A resistance in series with the winding that is part of everything the drive measures (the
  // calibration's Rs0 and every estimate) but not of the winding: the motor cable, per phase,
  // at 20 C (copper, at the ambient sensor's temperature). Eq. 1 and the copper loss take the
  // winding's share alone; 0: none (docs/estimator.md section 6, "A motor cable").
  double cable_resistance_20C_ohm = 0.0;
  // The standard uncertainty of the temperature a calibration refers Rs0 to (T0: the ambient /
  // coolant sensor's reading at the calibration, or the operator's): every estimate through
  // Eq. 1 shares its error, dT/dT0 = (K + T) / (K + T0), so no number of measurements averages
  // it away. It widens the reported band (and the derating's T + k sigma) once a calibration
  // run's Rs0 is in use; 0: the sensor taken as exact (docs/estimator.md section 6, "The
  // calibration's temperature").
  double reference_std_C = 0.0;
  // Thermal time runs this many times faster than controller time (test acceleration; 1 on a
  // real machine).
  double time_scale = 1.0;
  // Kalman filter.
  double initial_std_C = 5.0;
  double winding_process_std_C_per_sqrt_s = 0.02;  // per sqrt(thermal second)
  double housing_process_std_C_per_sqrt_s = 0.01;
  // The loss model's errors, random walks the measurements teach: k, the copper loss model's
  // relative error (the winding node gets (1 + k) times the computed loss), and dP, a loss the
  // model lacks (watts), on the housing node: the iron and friction losses, the rotor's heat,
  // a cooling path's error at one temperature (g below carries its part that scales with the
  // housing's rise). A commissioning's error in the winding's capacity or thermal
  // resistance acts like k: it scales with the loss, so what one load spell teaches carries
  // over to the next at another load; an error on the housing's side warms the winding and the
  // housing alike and leaves the winding's rise over the housing to the copper loss.
  double loss_error_process_std_W_per_sqrt_s = 0.5;
  double initial_loss_error_std_W = 50.0;
  double loss_scale_process_std_per_sqrt_s = 0.002;
  double initial_loss_scale_std = 0.2;
  // g, the cooling path's relative error: the housing sheds (1 + g) times what the modelled
  // housing-to-ambient resistance passes. Its heat goes with the housing's rise over the
  // ambient, so unlike dP it carries over from one temperature to the next: a catalogue's or a
  // commissioning's resistance to the ambient depends on the mounting, the airflow and the
  // paths the two-node model lumps (an outrunner's bell, a flange on its machine), and is
  // rarely known to better than a quarter.
  double cooling_scale_process_std_per_sqrt_s = 0.0;
  double initial_cooling_scale_std = 0.25;
  double measurement_floor_std_C = 0.3;  // added in quadrature to each measurement's own error
  double gate_sigma = 6.0;               // innovation gate (from the first fused measurement on)
  // Huber's weight: a measurement whose innovation lies beyond this many sigma (and inside the
  // gate) is fused with its variance scaled by |innovation| / (huber_sigma sigma), so that it
  // moves the state as far as one at huber_sigma would and no further. A resistance estimate's
  // error has heavier tails than its error bar's Gaussian (a field-weakening pair's bridge
  // pattern, a pulse crowded by a load step): one such estimate must not pull the winding and
  // the learned loss and cooling errors by its whole distance. At or above gate_sigma it is off;
  // the configuration accepts 1 to 1000.
  double huber_sigma = 3.0;
  // A start without a known winding temperature (no calibration run, no stored state): the
  // filter starts at the ambient sensor with this uncertainty and takes its first
  // measurement without the gate (a warm motor must not be rejected as implausible).
  double unknown_initial_std_C = 30.0;
  // An extra, unlearned share of the model's error: between measurements the winding's
  // uncertainty grows by this fraction of how far the model has carried the estimate since the
  // last one. Off by default: the loss-error states' priors already widen the band with the
  // predicted heating (k's prior is 20 % of the copper loss), and an error held apart from them
  // takes every innovation after a spell without measurements into the winding alone, so the
  // spell teaches the loss model nothing (docs/estimator.md §7, "An honest band").
  double model_error_fraction = 0.0;
  // A motor at rest (the drive disabled: predict() told that no losses run) or a stored state
  // cooled through a downtime (restore()): no loss runs to teach the loss states, so the band
  // grows by this fraction of the change the model predicts meanwhile (the cooling path's
  // relative error; counted on top of what g's variance adds through the housing, a
  // conservative overlap: a winding cools mostly through its path to the housing, which g
  // does not scale).
  double downtime_error_fraction = 0.25;
};

// What the drive keeps across a restart (a warm motor): the filter's temperatures and their
// uncertainty, and what it has learned of the loss model (dP and k with their
// standard deviations) and of the cooling path (g), which a power cycle does not change.
struct ThermalState {
  double winding_C = 0.0;
  double housing_C = 0.0;
  double winding_std_C = 0.0;
  bool has_loss_errors = false;   // false: a state without them (an older file): the priors
  double missing_loss_W = 0.0;    // dP
  double missing_loss_std_W = 0.0;
  double loss_scale_error = 0.0;  // k
  double loss_scale_std = 0.0;
  double loss_correlation = 0.0;  // of dP and k (at one load the filter learns a combination of dP and k Pcu)
  bool has_cooling_error = false;   // false: a state without g (an older file): its prior
  double cooling_scale_error = 0.0; // g
  double cooling_scale_std = 0.0;
};

// A data sheet's resistance, +-10 % read as two standard deviations.
inline constexpr double kNameplateRs0StdFraction = 0.05;

struct Calibration {
  double rs0_ohm = 0.133;       // the resistance the drive measures at t0_C (winding, and a cable at t0_C)
  double t0_C = 25.0;
  double ke0_V_s_per_rad = 0.0; // EMF constant (Eq. 3 form) at t0_C; 0 when not calibrated
  // Its standard error from the calibration's events; 0 when unknown (entered by hand, or
  // stored by a version that did not keep it): DriveController then assumes
  // kUnknownKe0StdFraction of Ke0.
  double ke0_std_V_s_per_rad = 0.0;
  bool calibrated = false;      // from a calibration run rather than the nameplate
  // The relative standard uncertainty of an Rs0 no calibration run measured (calibrated false:
  // the nameplate's, or one entered by hand): every measurement through Eq. 1 shares its error,
  // so no number of them averages it away. It widens the reported band, (K + T) times it
  // (dT/dRs0 of Eq. 1 referred to T0), once the filter holds a measurement made with it; a
  // calibration run replaces it (0: a calibrated Rs0's own error is shared by the running
  // estimates, which the ratio of Eq. 1 cancels in part, docs/accuracy.md).
  double rs0_std_fraction = 0.0;
  // The bridge's zero-current band from the calibration's sweep (inverter_sweep.hpp); 0 when
  // the calibration did not measure it (control.dead_time_band_A then holds).
  double dead_time_band_A = 0.0;
  // The correction of the commissioned rotor-angle offset (sensors.encoder_offset_rad) the
  // calibration's angle check measured (angle_check.hpp), electrical radians added to the
  // controller's angle; not measured: the configured offset holds.
  bool angle_correction_measured = false;
  double angle_correction_rad = 0.0;
  // The bridge's voltage error Vx (docs/estimator.md section 4) the calibration's events
  // learned together with Rs0, and its standard error; vx_std_V 0 when not learned (entered by
  // hand without it, or stored by a version that did not keep it): the configured prior
  // (injection.vx_initial_V) then holds. A stored one is the estimator's prior at start-up, so
  // that a restarted drive whose events cannot learn Vx (unipolar or fixed-angle pairs, or
  // under load) does not fall back to a guess several volts wide.
  double vx_V = 0.0;
  double vx_std_V = 0.0;
  // The bus the calibration's events learned Vx on (0: the reference bus, as before it was kept).
  // vx_V is referred to the reference bus; vx_std_V is its error at this bus, where the events
  // measured it: away from it the bus slope's uncertainty adds (docs/estimator.md section 4).
  double vx_bus_V = 0.0;
  // The standard uncertainty T0 carries beyond the sensor's (ThermalModelConfig::reference_std_C):
  // a calibration on the nameplate's Rs0 refers Rs0 to the ambient plus the thermal model's rise
  // by the drive's own losses since a soaked start, and that rise is known to
  // DriveConfig::calibration_model_rise_std_fraction of itself. 0: none (a calibration at rest on
  // the ambient, an operator's reading, a stored one from before this was kept).
  double t0_rise_std_C = 0.0;
};

struct DeratingConfig {
  double max_current_A = 80.0;      // |i| limit when cold (peak; Table I: Istall 166 A peak)
  double min_current_A = 10.0;      // the floor at the temperature limit
  double derate_start_C = 130.0;    // derating begins here (upper bound of the estimate)
  double limit_C = 155.0;           // winding temperature limit (insulation class F)
  double confidence_sigma = 2.0;    // derate on T + k sigma
  // The magnets: NdFeB loses flux irreversibly above its grade's working temperature, the more
  // so under the demagnetising field of negative d current (field weakening). The current
  // limit falls linearly on the magnet estimate from magnet_start_C to magnet_limit_C, down to
  // min_current_A (defaults: an SH grade, 150 C).
  double magnet_start_C = 130.0;
  double magnet_limit_C = 150.0;
};

struct ThermalEstimate {
  double winding_C = 0.0;
  double winding_std_C = 0.0;
  double housing_C = 0.0;
  double loss_error_W = 0.0;      // the heat the model lacks: dP (housing) plus k times the last period's copper loss (winding); without g's share
  double missing_loss_W = 0.0;    // dP
  double loss_scale_error = 0.0;  // k
  double loss_scale_std = 0.0;    // its standard deviation
  double time_since_measurement_s = 0.0;
  double cooling_scale_error = 0.0;  // g: the housing sheds (1 + g) times what the model's path passes
};

// What an estimate's resistance owes to the error of the bus slope it was referred with
// (docs/estimator.md section 4, "The bus slope's error, learned under load"). The bridge's
// voltage error Vx is referred from the bus it was learned at to the event's by a slope (the
// dead time's share of the bus); an event that cannot learn Vx (its current vector does not
// reverse: under load) holds Vx there, and the slope's error times the bus's distance moves its
// resistance by drs/dVx of it. The filter carries that error as a state, shared by every such
// estimate: estimates at different loads and buses, with the winding carried between them by
// the thermal model, tell it from the winding's temperature.
struct BusSlopeTerm {
  // dRs / d(slope error), ohm per V/V: -drs/dVx times the event's bus distance from where Vx
  // is known; 0: the estimate has no such term (it learned its own Vx, or no slope is learned).
  double sensitivity_ohm = 0.0;
  double slope = 0.0;      // the slope (V/V) the estimate was referred with
  double slope_var = 0.0;  // its variance: the state's prior when the slope is new to the filter
  // A term the filter takes: a finite, nonzero sensitivity and a finite slope with a positive,
  // finite variance (otherwise the estimate's error bar keeps the slope's share).
  [[nodiscard]] bool usable() const noexcept {
    return sensitivity_ohm != 0.0 && std::isfinite(sensitivity_ohm) && std::isfinite(slope) && slope_var > 0.0 &&
           std::isfinite(slope_var);
  }
};

class ThermalObserver {
 public:
  static constexpr int kStates = 6;
  // The bus slope's error (BusSlopeTerm), V/V: the last state.
  static constexpr int kBusSlopeState = 5;
  // The bounds the filter holds k and g within (a thermal state file's reader too): the
  // machine's copper loss, and its cooling path, between half and twice the model's.
  static constexpr double kMinLossScale = -0.5;
  static constexpr double kMaxLossScale = 1.0;
  static constexpr double kMinCoolingScale = -0.5;
  static constexpr double kMaxCoolingScale = 1.0;
  using Matrix = Eigen::Matrix<double, kStates, kStates>;
  using Vector = Eigen::Matrix<double, kStates, 1>;
  // known: the winding is at initial_temp_C (a soaked motor at a calibration) with
  // config.initial_std_C; otherwise a guess with config.unknown_initial_std_C, and the first
  // measurement passes without the gate.
  ThermalObserver(const ThermalModelConfig& config, const Calibration& calibration,
                  double initial_temp_C, bool known = true);

  // A state kept from before a restart, cooled through the downtime by the model (no
  // losses, the ambient given), its uncertainty grown by the model error of that cooling.
  // The first measurement afterwards passes without the gate: the stored state is a
  // prediction, not a measurement.
  void restore(const ThermalState& state, double downtime_thermal_s, double ambient_C);
  // The ambient of the restart, first read after restore() and before the first predict(),
  // differs from the stored one that the downtime's cooling assumed: the ambient moved some time
  // in the downtime, to an unknown schedule. The network relaxed towards the stored ambient and
  // towards this one bound the state: span = (ambient_C - stored) (I - e^{A t}) [1 1]'. The state
  // takes the middle of the two and its variance (span / 4)^2 more, fully shared by the nodes, so
  // that its 2 sigma reaches either end. Returns the winding's shift (0 when nothing was done:
  // no restore pending, the same ambient, or a predict() or a measurement since).
  double refer_restored_to_ambient(double ambient_C);
  // The winding's rise over the ambient by the drive's own losses as the model alone carries it:
  // driven by the computed losses only (no measurement, no learned loss error, and no ambient, so
  // that an ambient reading that arrives late or moves does not count as warmth), from 0 at a
  // guess, from a restored state's rise (not below 0), carried over a calibration's restart
  // (keep_model_rise). Before a calibration the measurements go through the nameplate's Rs0,
  // whose error (a few per cent: over ten kelvin) hides a rise of a few kelvin; this is what the
  // drive's own losses did since the soaked start a calibration on the ambient assumes.
  [[nodiscard]] double model_rise_C() const { return model_rise_K_(0); }
  // Restarts from a guess (see the constructor), e.g. the ambient sensor's temperature.
  void restart_unknown(double guess_C);
  // Takes over what `other` has learned of the loss model and the cooling path (dP, k, g and
  // their covariance), as
  // when the temperatures restart (a calibration) but the machine is the same.
  void keep_loss_errors(const ThermalObserver& other);
  // Takes over `other`'s model-only rise (model_rise_C), winding and housing: the drive's own
  // warmth survives a calibration's restart of the temperatures.
  void keep_model_rise(const ThermalObserver& other) { model_rise_K_ = other.model_rise_K_; }
  [[nodiscard]] bool anchored() const { return anchored_; }
  [[nodiscard]] ThermalState state() const;

  // Advances the model by dt (controller seconds) with the losses of that interval.
  // copper_current_sq_A2 is the mean of id^2 + iq^2; the copper loss is computed with Rs at the
  // estimated winding temperature (Eq. 1).
  // at_rest: the drive drove no current over the interval (disabled): the change the model
  // predicts meanwhile widens the band by downtime_error_fraction.
  void predict(double dt_s, double copper_current_sq_A2, double omega_m_rad_s, double ambient_C,
               bool at_rest = false);

  // Fuses one resistance measurement (ohm, with its standard error). Returns false, leaving
  // the state alone, when the measurement is further from the prediction than gate_sigma
  // standard deviations of the innovation: one wild estimate must not swing the derating.
  // `systematic_std_ohm` is the part of the error bar shared by consecutive measurements
  // (included in rs_std_ohm too): fusing more such measurements cannot average it away, so
  // the state carries a share of it (k of this one's plus 1 - k of what it carried) that the
  // reported band adds in quadrature; the gain is unchanged.
  // `age_s` (controller seconds) is how long ago the measurement's time lies (an event's
  // pairs take up to seconds while the winding warms or cools): the innovation is taken
  // against the filter's winding estimate of that time, from the last kHistory updates.
  // `from_age_s` > `to_age_s`: the measurement is the line through the winding's resistance at
  // those ages, taken at age_s (EventEstimate::measured_from_s), and is compared with the same
  // line through the filter's trajectory.
  // `bus_slope`: the estimate's share of the bus slope's error (BusSlopeTerm); when it is
  // usable(), rs_std_ohm and systematic_std_ohm exclude that share, which the state carries. The
  // first usable term starts the state at 0 with the slope's variance, and so does a slope whose
  // variance grew (started afresh from its prior); one the estimator has learned since (its
  // variance fell) is fused as a measurement of the state, which is then referred to the moved
  // slope (refer_bus_slope).
  bool update_resistance(double rs_ohm, double rs_std_ohm, double systematic_std_ohm = 0.0,
                         double age_s = 0.0, double from_age_s = 0.0, double to_age_s = 0.0,
                         const BusSlopeTerm& bus_slope = {});
  // The bus slope's error the filter has learned (V/V) and its standard deviation; 0 and 0
  // before an estimate brought one.
  [[nodiscard]] double bus_slope_error() const { return x_(kBusSlopeState); }
  [[nodiscard]] double bus_slope_error_std() const;
  // The housing estimate's standard deviation (C), from the filter's covariance.
  [[nodiscard]] double housing_std_C() const;

  // The filter's winding estimate `age_s` controller seconds before its last update, from the
  // history below (linear between updates; before the oldest kept, the oldest), moved by the
  // jumps of the state since (a fusion), so that differences are the model's predictions.
  [[nodiscard]] double winding_at_age_C(double age_s) const;

  void set_calibration(const Calibration& c);
  void set_time_scale(double time_scale) { config_.time_scale = time_scale; }
  [[nodiscard]] double time_scale() const { return config_.time_scale; }
  [[nodiscard]] const Calibration& calibration() const { return calibration_; }

  [[nodiscard]] ThermalEstimate estimate() const;
  // The band's share from an uncalibrated Rs0 (Calibration::rs0_std_fraction), 1 sigma, C.
  [[nodiscard]] double uncalibrated_rs0_std_C() const;
  // The same share for a winding at temp_C, whether or not the filter has measured through that
  // Rs0 yet (0 for a calibration run's Rs0).
  [[nodiscard]] double rs0_std_C_at(double temp_C) const;
  // The band's share from the calibration's T0 (ThermalModelConfig::reference_std_C), 1 sigma, C.
  [[nodiscard]] double reference_std_C() const;
  // The band's variance without those shares (C^2): what the filter itself holds, which a stored
  // state keeps and a resistance taken back through the same Rs0 carries.
  [[nodiscard]] double measured_winding_variance_C2() const;
  // The winding's rate of change over the last predict() (C per controller second).
  [[nodiscard]] double winding_rate_C_per_s() const { return winding_rate_C_per_s_; }
  // Eq. 1 between what the drive measures (the winding's resistance plus the cable's,
  // ThermalModelConfig::cable_resistance_20C_ohm) and the winding's temperature.
  [[nodiscard]] double temperature_from_resistance_C(double rs_ohm) const;
  [[nodiscard]] double resistance_at_C(double temp_C) const;
  // The cable's share of a measured resistance now: at the ambient of the last predict() or
  // restore() (before either, at the calibration's T0); and the winding's share of Rs0.
  [[nodiscard]] double cable_resistance_now_ohm() const;
  [[nodiscard]] double winding_rs0_ohm() const { return winding_rs0_ohm_; }

  // Time (controller seconds) until the winding reaches limit_C if the present load
  // continues; nothing when the steady state stays below the limit. The copper loss is taken
  // at the limit's resistance; copper_loss_per_housing_C (1/K) is its relative growth per
  // kelvin the housing warms (at a held torque the current rises as the magnets' flux falls:
  // DriveController passes -2 beta / (1 + beta (T_magnet - T0))), 0 for a loss held constant.
  [[nodiscard]] bool time_to_limit_s(double limit_C, double copper_current_sq_A2,
                                     double omega_m_rad_s, double ambient_C, double* out_s,
                                     double copper_loss_per_housing_C = 0.0) const;

  // Copper loss for a mean current square at the estimated temperature.
  [[nodiscard]] double copper_loss_W(double copper_current_sq_A2) const;
  [[nodiscard]] double iron_loss_W(double omega_m_rad_s) const;

 private:
  // What keeps the missing loss dP and the cooling's error g together (dP - g (Th - Ta)/Rha)
  // from taking more heat out of the housing than a machine can lose: the iron loss and once
  // more what the modelled path to the ambient takes out.
  // share: the housing's path at the speed in question (housing_cooling_share).
  [[nodiscard]] double housing_loss_floor_W(double iron_loss_W, double ambient_C, double share) const;
  // Eq. 1 for the winding alone (without the cable).
  [[nodiscard]] double winding_resistance_at_C(double temp_C) const;
  ThermalModelConfig config_;
  Calibration calibration_;
  double winding_rs0_ohm_ = 0.0;  // the winding's share of calibration_.rs0_ohm (set_calibration)
  // The bus slope the last state refers to (BusSlopeTerm): its value and variance, and whether
  // the state holds one.
  void refer_bus_slope(const BusSlopeTerm& term);
  void clear_bus_slope();
  bool bus_slope_active_ = false;
  double bus_slope_ref_ = 0.0;
  double bus_slope_ref_var_ = 0.0;
  // winding C, housing C, the missing loss dP W, the copper loss's relative error k, the
  // cooling's g, the bus slope's error (V/V)
  Vector x_;
  // The model's rise of winding and housing by the drive's own losses (model_rise_C), K.
  Eigen::Vector2d model_rise_K_ = Eigen::Vector2d::Zero();
  double last_copper_loss_W_ = 0.0;
  double winding_rate_C_per_s_ = 0.0;
  Matrix p_;
  double since_measurement_s_ = 0.0;
  double anchor_C_ = 0.0;     // the winding estimate the last measurement (or the start) left
  double shared_error_C_ = 0.0;  // the state's share of measurements' shared model error
  double drift_std_C_ = 0.0;  // the model's error since then (model_error_fraction, at rest)
  double rest_drift_C_ = 0.0; // its part from the spells at rest (downtime_error_fraction)
  bool anchored_ = true;      // a measurement or a known temperature holds the state
  // From restore() to the first predict(): the downtime's relaxation e^{A t} and the ambient
  // it assumed (refer_restored_to_ambient).
  bool restore_referable_ = false;
  Eigen::Matrix2d restore_relaxation_ = Eigen::Matrix2d::Identity();
  double restore_ambient_C_ = 0.0;
  double ambient_C_ = std::numeric_limits<double>::quiet_NaN();  // the last predict()'s or restore()'s
  bool holds_uncalibrated_ = false;  // a measurement through an uncalibrated Rs0 is in the state
  int gated_in_row_ = 0;      // measurements gated out since the last fused one
  double gated_sum_C_ = 0.0, gated_sq_sum_C2_ = 0.0, gated_r_sum_C2_ = 0.0;  // of those
  static constexpr int kReanchorAfterGated = 5;
  // The winding estimate after each of the last predict() calls (controller seconds on a
  // clock of the observer's own), for measurements that belong to a moment past. A fusion's
  // jump moves the kept trajectory with the state (history_offset_C_); a restart (restore())
  // starts it afresh from the new state.
  static constexpr std::size_t kHistory = 256;  // 2.56 s at the 10 ms thermal update
  std::array<double, kHistory> history_C_{};
  std::array<double, kHistory> history_s_{};
  std::size_t history_size_ = 0;
  std::size_t history_next_ = 0;
  double clock_s_ = 0.0;
  double history_offset_C_ = 0.0;  // added to the kept values: the fusions' jumps since they were kept
  void restart_history();  // only the present state: after a restart
  [[nodiscard]] std::size_t history_oldest() const noexcept;  // the oldest kept entry's index
  [[nodiscard]] bool reanchor_consistent(double z, double r) const;
  void cap_variance(int i, double limit);
  void set_loss_errors(double dp_W, double dp_std_W, double k, double k_std, double correlation,
                       double elapsed_thermal_s);
  void set_cooling_error(double g, double g_std, double elapsed_thermal_s);
};

// The housing's path to the ambient at the mechanical speed omega_m_rad_s, as a share of
// 1 / housing_to_ambient_K_W: exactly 1 without a shaft fan (fan_speed_rad_s 0); with one,
// |speed| held at math::kFanSpeedSpan times the fan's speed beyond it (common/math/pmsm/shaft_fan.hpp,
// the plant's formula too).
[[nodiscard]] double housing_cooling_share(const ThermalModelConfig& c, double omega_m_rad_s);

// The thermal model's fastest time constant (thermal seconds): the two-node network's faster
// mode, about the winding's capacity times its resistance to the housing (with the housing's
// path at its largest share: a shaft fan's at kFanSpeedSpan times its speed). The filter's
// prediction (a second-order step) stays accurate while an update's thermal time,
// thermal.update_s x thermal.acceleration, is at most kMaxThermalStepPerTimeConstant of it;
// beyond twice it the step diverges (a configuration check refuses that).
[[nodiscard]] double thermal_model_fastest_time_constant_s(const ThermalModelConfig& c);
inline constexpr double kMaxThermalStepPerTimeConstant = 0.5;

// The derated current limit and whether derating is active, from the estimate's upper bound.
struct DeratingResult {
  double current_limit_A = 0.0;
  bool derating = false;
};
[[nodiscard]] DeratingResult derate(const DeratingConfig& config, const ThermalEstimate& e);
// The current limit for a magnet temperature (the caller passes its estimate's upper bound).
[[nodiscard]] DeratingResult derate_magnet(const DeratingConfig& config, double magnet_C);

}  // namespace pmsm::core
