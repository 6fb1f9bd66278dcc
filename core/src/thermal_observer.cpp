#include "pmsm/core/thermal_observer.hpp"

#include <algorithm>
#include <cmath>

#include "pmsm/core/machine_equations.hpp"
#include "pmsm/shaft_fan.hpp"

namespace pmsm::core {
namespace {

// Continuous-time matrices of the two-node network with the three model-error states: k, the
// copper loss model's relative error, in the winding; dP, a loss the model lacks (watts), in
// the housing: the iron and friction losses, the rotor's heat, a cooling path's error at one
// temperature, all on the housing's side; and g, the cooling path's relative error, which
// scales with the housing's rise (a commissioning's error in the winding's own path scales with the copper
// loss, which is k's; docs/estimator.md section 7):
// Cw dTw/dt = (1 + k) Pcu - (Tw - Th)/Rwh
// Ch dTh/dt = Pfe + dP + (Tw - Th)/Rwh - (1 + g) (Th - Ta)/Rha
// d(dP)/dt  = 0, dk/dt = 0, dg/dt = 0 (random walks)
// The k column carries this period's copper loss: the system is linear in the state for a
// known loss, time-varying with it. The cooling's error g multiplies the housing's rise, which
// is a state: the matrix holds the path at the learned conductance (1 + g) Rha^-1, and g's
// column, the rise it multiplies (the Jacobian's, for the covariance), is set by predict().
// share: the housing's path at the present speed, as a share of the modelled one (a shaft fan's,
// housing_cooling_share; 1 without one).
ThermalObserver::Matrix system_matrix(const ThermalModelConfig& c, double copper_loss_W, double cooling_scale,
                                      double share) {
  const double gwh = 1.0 / c.winding_to_housing_K_W;
  const double gha = (1.0 + cooling_scale) * share / c.housing_to_ambient_K_W;
  ThermalObserver::Matrix a = ThermalObserver::Matrix::Zero();
  a(0, 0) = -gwh / c.winding_capacity_J_K;
  a(0, 1) = gwh / c.winding_capacity_J_K;
  a(0, 3) = copper_loss_W / c.winding_capacity_J_K;
  a(1, 0) = gwh / c.housing_capacity_J_K;
  a(1, 1) = -(gwh + gha) / c.housing_capacity_J_K;
  a(1, 2) = 1.0 / c.housing_capacity_J_K;
  return a;
}

}  // namespace

ThermalObserver::ThermalObserver(const ThermalModelConfig& config, const Calibration& calibration,
                                 double initial_temp_C, bool known)
    : config_(config), anchor_C_(initial_temp_C), anchored_(known) {
  set_calibration(calibration);
  const double std_C = known ? config.initial_std_C : config.unknown_initial_std_C;
  x_ << initial_temp_C, initial_temp_C, 0.0, 0.0, 0.0, 0.0;
  p_.setZero();
  p_(0, 0) = std_C * std_C;
  p_(1, 1) = std_C * std_C;
  if (!known) {
    // Unknown means the whole machine's temperature is unknown: winding and housing move
    // together (a warm motor is warm throughout), so the guess's error is shared; with
    // independent errors the model would shrink the winding's band by itself.
    p_(0, 1) = p_(1, 0) = 0.95 * std_C * std_C;
  }
  p_(2, 2) = config.initial_loss_error_std_W * config.initial_loss_error_std_W;
  p_(3, 3) = config.initial_loss_scale_std * config.initial_loss_scale_std;
  p_(4, 4) = config.initial_cooling_scale_std * config.initial_cooling_scale_std;
}

void ThermalObserver::restart_unknown(double guess_C) {
  *this = ThermalObserver(config_, calibration_, guess_C, false);
}

ThermalState ThermalObserver::state() const {
  ThermalState s;
  s.winding_C = x_(0);
  s.housing_C = x_(1);
  // The band without an uncalibrated Rs0's share or T0's: estimate() adds them again (uncalibrated_rs0_std_C, reference_std_C),
  // and a share stored in P would count twice and raise the gain.
  s.winding_std_C = std::sqrt(measured_winding_variance_C2());
  s.has_loss_errors = true;
  s.missing_loss_W = x_(2);
  s.missing_loss_std_W = std::sqrt(std::max(p_(2, 2), 0.0));
  s.loss_scale_error = x_(3);
  s.loss_scale_std = std::sqrt(std::max(p_(3, 3), 0.0));
  const double den = s.missing_loss_std_W * s.loss_scale_std;
  s.loss_correlation = den > 0.0 ? std::clamp(p_(2, 3) / den, -1.0, 1.0) : 0.0;
  // Only where g is learned: a stored 0 +- 0 from a filter with g off would hold g at 0 for good
  // once it is switched on.
  s.has_cooling_error = config_.initial_cooling_scale_std > 0.0;
  s.cooling_scale_error = x_(4);
  s.cooling_scale_std = std::sqrt(std::max(p_(4, 4), 0.0));
  return s;
}

void ThermalObserver::restore(const ThermalState& state, double downtime_thermal_s, double ambient_C) {
  // A stored state holds what the run before learned through the same Rs0.
  holds_uncalibrated_ = !calibration_.calibrated;
  // The two-node network without losses relaxes towards the ambient: x(t) = Ta + e^{A t} (x0 - Ta),
  // e^{A t} by scaling and squaring of a Taylor step (A's time constants are far above t / 2^n).
  // The cooling path as the run before learned it (g), within the filter's bounds.
  const bool cooling_learned = state.has_cooling_error && std::isfinite(state.cooling_scale_error) &&
                               std::isfinite(state.cooling_scale_std) && config_.initial_cooling_scale_std > 0.0;
  const double g = cooling_learned ? std::clamp(state.cooling_scale_error, kMinCoolingScale, kMaxCoolingScale) : 0.0;
  // At rest: a shaft fan stands still over the downtime.
  const Eigen::Matrix2d a = system_matrix(config_, 0.0, g, housing_cooling_share(config_, 0.0)).topLeftCorner<2, 2>();
  const double t = std::max(downtime_thermal_s, 0.0);
  int squarings = 0;
  double h = t;
  while (h > 1.0 && squarings < 60) {
    h *= 0.5;
    ++squarings;
  }
  Eigen::Matrix2d e = Eigen::Matrix2d::Identity() + a * h + 0.5 * a * a * h * h + a * a * a * (h * h * h / 6.0);
  for (int k = 0; k < squarings; ++k) {
    e = e * e;
  }
  const Eigen::Vector2d x0(state.winding_C - ambient_C, state.housing_C - ambient_C);
  const Eigen::Vector2d x1 = e * x0;
  const double cooled_by = std::abs(x1(0) - x0(0));
  x_ << ambient_C + x1(0), ambient_C + x1(1), 0.0, 0.0, 0.0, 0.0;
  clear_bus_slope();  // the estimator's slope restarts with it (its calibration's prior)
  model_rise_K_ = x1.cwiseMax(0.0);  // (a state stored below the ambient is no warmth of the drive's)
  anchor_C_ = x_(0);
  // The stored uncertainty, the model error of the cooling, and the process noise of the
  // downtime.
  const double drift = config_.downtime_error_fraction * cooled_by;
  const double stored = std::isfinite(state.winding_std_C) ? std::max(state.winding_std_C, config_.initial_std_C)
                                                          : config_.unknown_initial_std_C;
  const double var = stored * stored + drift * drift +
                     config_.winding_process_std_C_per_sqrt_s * config_.winding_process_std_C_per_sqrt_s * t;
  p_.setZero();
  p_(0, 0) = var;
  p_(1, 1) = var;
  p_(0, 1) = p_(1, 0) = 0.95 * var;  // the machine's error is shared (see the constructor)
  // The loss model's errors are the machine's, not the moment's: what the last run learned
  // holds, less certain by the random walks over the downtime (set_loss_errors).
  const bool learned = state.has_loss_errors && std::isfinite(state.missing_loss_W) &&
                       std::isfinite(state.missing_loss_std_W) && std::isfinite(state.loss_scale_error) &&
                       std::isfinite(state.loss_scale_std) && std::isfinite(state.loss_correlation);
  if (learned) {
    set_loss_errors(state.missing_loss_W, state.missing_loss_std_W, state.loss_scale_error, state.loss_scale_std,
                    state.loss_correlation, t);
  } else {
    set_loss_errors(0.0, config_.initial_loss_error_std_W, 0.0, config_.initial_loss_scale_std, 0.0, 0.0);
  }
  set_cooling_error(g, cooling_learned ? state.cooling_scale_std : config_.initial_cooling_scale_std,
                    cooling_learned ? t : 0.0);
  drift_std_C_ = 0.0;
  rest_drift_C_ = 0.0;
  shared_error_C_ = 0.0;  // part of the stored band now
  since_measurement_s_ = 0.0;
  restart_history();  // a state from before the restart: nothing of this run to look back on
  anchored_ = false;
  restore_referable_ = true;
  restore_relaxation_ = e;
  restore_ambient_C_ = ambient_C;
  ambient_C_ = ambient_C;
}

double ThermalObserver::refer_restored_to_ambient(double ambient_C) {
  if (!restore_referable_) {
    return 0.0;
  }
  restore_referable_ = false;
  const double moved = ambient_C - restore_ambient_C_;
  if (!std::isfinite(moved) || moved == 0.0) {
    return 0.0;
  }
  // Each node's end temperature under the two ambients differs by the part of the ambient's
  // step the network took up over the downtime: moved (1 - row sum of e^{A t}).
  const Eigen::Vector2d span = moved * (Eigen::Vector2d::Ones() - restore_relaxation_ * Eigen::Vector2d::Ones());
  x_(0) += 0.5 * span(0);
  x_(1) += 0.5 * span(1);
  model_rise_K_ = (x_.head<2>() - Eigen::Vector2d::Constant(ambient_C)).cwiseMax(0.0);
  anchor_C_ = x_(0);
  const Eigen::Vector2d s = 0.25 * span;
  p_.topLeftCorner<2, 2>() += s * s.transpose();
  return 0.5 * span(0);
}

void ThermalObserver::set_loss_errors(double dp_W, double dp_std_W, double k, double k_std, double correlation,
                                      double elapsed_thermal_s) {
  const double p2 = config_.initial_loss_error_std_W * config_.initial_loss_error_std_W;
  const double p3 = config_.initial_loss_scale_std * config_.initial_loss_scale_std;
  // Bounded as in the filter: k within [-0.5, 1], and a missing loss no further than five of
  // its prior's standard deviations (beyond, it is no error of this model: a file from
  // another machine or model). A state without a prior (learning switched off) stays at 0.
  const double dp_bound = 5.0 * config_.initial_loss_error_std_W;
  x_(2) = std::clamp(dp_W, -dp_bound, dp_bound);
  x_(3) = p3 > 0.0 ? std::clamp(k, kMinLossScale, kMaxLossScale) : 0.0;
  // The random walks over the time since, capped at the priors (as predict() does).
  const double q2 = config_.loss_error_process_std_W_per_sqrt_s * config_.loss_error_process_std_W_per_sqrt_s *
                    elapsed_thermal_s;
  const double q3 = config_.loss_scale_process_std_per_sqrt_s * config_.loss_scale_process_std_per_sqrt_s *
                    elapsed_thermal_s;
  const double s2 = std::sqrt(std::min(dp_std_W * dp_std_W + q2, p2));
  const double s3 = std::sqrt(std::min(k_std * k_std + q3, p3));
  p_.block<2, 2>(0, 2).setZero();
  p_.block<2, 2>(2, 0).setZero();
  p_(2, 2) = s2 * s2;
  p_(3, 3) = s3 * s3;
  // At one load the filter learns a combination of dP and k Pcu better than either (the two
  // heat the winding alike there, the one through the housing): their correlation is kept
  // (bounded by 1, so P stays positive semi-definite).
  p_(2, 3) = p_(3, 2) = std::clamp(correlation, -1.0, 1.0) * s2 * s3;
}

void ThermalObserver::set_cooling_error(double g, double g_std, double elapsed_thermal_s) {
  const double p4 = config_.initial_cooling_scale_std * config_.initial_cooling_scale_std;
  x_(4) = p4 > 0.0 ? std::clamp(g, kMinCoolingScale, kMaxCoolingScale) : 0.0;
  const double q4 = config_.cooling_scale_process_std_per_sqrt_s * config_.cooling_scale_process_std_per_sqrt_s *
                    elapsed_thermal_s;
  p_.row(4).setZero();
  p_.col(4).setZero();
  // (Its correlation with dP and k is not kept: the stored state holds g and its deviation.)
  p_(4, 4) = std::min(g_std * g_std + q4, p4);
}

void ThermalObserver::keep_loss_errors(const ThermalObserver& other) {
  // The same model's states: taken over as they are (their covariance with the temperatures,
  // which restart, is dropped). Not the bus slope's error: a calibration learns the bridge afresh.
  constexpr int kLoss = 3;  // dP, k, g
  x_.segment<kLoss>(2) = other.x_.segment<kLoss>(2);
  p_.topRightCorner<2, kStates - 2>().setZero();
  p_.bottomLeftCorner<kStates - 2, 2>().setZero();
  p_.block<kLoss, kLoss>(2, 2) = other.p_.block<kLoss, kLoss>(2, 2);
  clear_bus_slope();
}

void ThermalObserver::clear_bus_slope() {
  x_(kBusSlopeState) = 0.0;
  p_.row(kBusSlopeState).setZero();
  p_.col(kBusSlopeState).setZero();
  bus_slope_active_ = false;
  bus_slope_ref_ = 0.0;
  bus_slope_ref_var_ = 0.0;
}

void ThermalObserver::refer_bus_slope(const BusSlopeTerm& term) {
  // The state is the error of the slope the estimates are referred with, b - slope. The
  // estimator learns the slope from its own events (a Vx measured unloaded at a bus, docs/
  // estimator.md section 4): the slope moves by `move` and its variance falls from p_prev to
  // p_new. Those events are data the filter has not seen, and their information beyond the
  // estimator's earlier belief is a measurement of b (in the frame of the slope before the move):
  // y = r move / p_new with the variance r, 1 / r = 1 / p_new - 1 / p_prev (the two Gaussians'
  // quotient). The filter fuses it, then refers its state to the moved slope. A variance that
  // grew (a calibration, or a stored Vx, starts the slope afresh from its prior) is a new slope:
  // the state restarts from it.
  constexpr double kRelative = 1e-9;  // a variance the same but for rounding
  if (!bus_slope_active_ || term.slope_var > bus_slope_ref_var_ * (1.0 + kRelative)) {
    clear_bus_slope();
    p_(kBusSlopeState, kBusSlopeState) = term.slope_var;
    bus_slope_active_ = true;
  } else {
    const double move = term.slope - bus_slope_ref_;
    const double p_prev = bus_slope_ref_var_;
    const double p_new = term.slope_var;
    if (p_prev - p_new > kRelative * p_prev) {
      const double r = p_new * p_prev / (p_prev - p_new);
      const double y = r * move / p_new;
      const double s = p_(kBusSlopeState, kBusSlopeState) + r;
      if (std::isfinite(r) && std::isfinite(y) && s > 0.0) {
        // A Kalman update with h the state's unit row, in Joseph form (as update_resistance's).
        Eigen::Matrix<double, 1, kStates> h = Eigen::Matrix<double, 1, kStates>::Zero();
        h(kBusSlopeState) = 1.0;
        const Vector k = p_.col(kBusSlopeState) / s;
        const double before_C = x_(0);
        x_ += k * (y - x_(kBusSlopeState));
        const Matrix i_kh = Matrix::Identity() - k * h;
        p_ = i_kh * p_ * i_kh.transpose() + k * r * k.transpose();
        x_(3) = std::clamp(x_(3), kMinLossScale, kMaxLossScale);
        x_(4) = std::clamp(x_(4), kMinCoolingScale, kMaxCoolingScale);
        history_offset_C_ += x_(0) - before_C;  // the winding moved with it (update_resistance)
      }
    }
    x_(kBusSlopeState) -= move;
  }
  bus_slope_ref_ = term.slope;
  bus_slope_ref_var_ = term.slope_var;
}

double ThermalObserver::bus_slope_error_std() const {
  return std::sqrt(std::max(p_(kBusSlopeState, kBusSlopeState), 0.0));
}

double ThermalObserver::housing_std_C() const { return std::sqrt(std::max(p_(1, 1), 0.0)); }

double ThermalObserver::cable_resistance_now_ohm() const {
  // A copper cable at the ambient sensor's temperature, its resistance given at 20 C.
  return cable_resistance_at_C(config_.cable_resistance_20C_ohm,
                               std::isfinite(ambient_C_) ? ambient_C_ : calibration_.t0_C);
}

void ThermalObserver::set_calibration(const Calibration& c) {
  calibration_ = c;
  // Rs0 holds the winding and the cable both at T0 (a calibration refers its events so:
  // resistance_referred_to_C).
  winding_rs0_ohm_ = c.rs0_ohm - cable_resistance_at_C(config_.cable_resistance_20C_ohm, c.t0_C);
}

double ThermalObserver::winding_resistance_at_C(double temp_C) const {
  return resistance_at_temperature_ohm(winding_rs0_ohm_, calibration_.t0_C, temp_C,
                                       config_.conductor_inferred_zero_C);  // Eq. 1
}

double ThermalObserver::resistance_at_C(double temp_C) const {
  return winding_resistance_at_C(temp_C) + cable_resistance_now_ohm();
}

double ThermalObserver::temperature_from_resistance_C(double rs_ohm) const {
  return core::temperature_from_resistance_C(rs_ohm - cable_resistance_now_ohm(), winding_rs0_ohm(), calibration_.t0_C,
                                             config_.conductor_inferred_zero_C);  // Eq. 1
}

double ThermalObserver::copper_loss_W(double copper_current_sq_A2) const {
  // Amplitude-invariant dq: P = 3/2 Rs (id^2 + iq^2), the winding's Rs (the cable's loss is
  // outside the machine).
  return 1.5 * winding_resistance_at_C(x_(0)) * copper_current_sq_A2;
}

double ThermalObserver::housing_loss_floor_W(double iron_loss_W, double ambient_C, double share) const {
  // A machine makes no cold. The missing loss dP may be negative: the model's iron loss too
  // high, or its cooling path too weak, which takes more heat out the warmer the housing is.
  // But at most all of the iron loss and once more what the modelled path takes out (a cooling
  // path twice as good as modelled): beyond that, a dP learned while the housing was warm (or
  // from estimates that read low) would cool a motor at rest below its coolant, and the stored
  // state would carry that to the next start. What the linear model's dP term puts below that
  // floor is added back.
  // The learned cooling's error g is such a loss too: -g (Th - Ta) / Rha.
  const double rise_C = std::max(x_(1) - ambient_C, 0.0);
  const double gha = share / config_.housing_to_ambient_K_W;
  return std::max(-iron_loss_W - rise_C * gha - (x_(2) - x_(4) * rise_C * gha), 0.0);
}

double ThermalObserver::iron_loss_W(double omega_m_rad_s) const {
  const double w = std::abs(omega_m_rad_s);
  return config_.iron_loss_k1_W_s_rad * w + config_.iron_loss_k2_W_s2_rad2 * w * w;
}

void ThermalObserver::predict(double dt_s, double copper_current_sq_A2, double omega_m_rad_s,
                              double ambient_C, bool at_rest) {
  restore_referable_ = false;  // the state has moved on under the ambient it was given
  ambient_C_ = ambient_C;
  const double dt = dt_s * config_.time_scale;  // thermal seconds
  const double pcu = copper_loss_W(copper_current_sq_A2);
  last_copper_loss_W_ = pcu;
  const double share = housing_cooling_share(config_, omega_m_rad_s);  // a shaft fan's at this speed
  Matrix a = system_matrix(config_, pcu, x_(4), share);
  const Eigen::Matrix2d a_model = system_matrix(config_, pcu, 0.0, share).topLeftCorner<2, 2>();  // g = 0
  const double pfe = iron_loss_W(omega_m_rad_s);
  const double gha_ch = share / (config_.housing_to_ambient_K_W * config_.housing_capacity_J_K);
  const double cooling = 1.0 + x_(4);  // the learned path's share of the modelled one
  // The inputs: they enter the temperatures' rows alone.
  Eigen::Vector2d u(pcu / config_.winding_capacity_J_K, pfe / config_.housing_capacity_J_K + cooling * ambient_C * gha_ch);
  // g's column for the covariance: d(dTh/dt)/dg = -(Th - Ta) / (Rha Ch) at the estimate.
  double g_column = -(x_(1) - ambient_C) * gha_ch;
  {
    // The model's rise by the drive's own losses (model_rise_C): the network's block, the computed
    // losses without the ambient's term (no dP, no k, so the floor below never binds for it), the
    // same step as the filter's.
    const Eigen::Matrix2d& a2 = a_model;
    const Eigen::Matrix2d b2 = Eigen::Matrix2d::Identity() * dt + 0.5 * a2 * dt * dt;
    const Eigen::Vector2d losses(pcu / config_.winding_capacity_J_K, pfe / config_.housing_capacity_J_K);
    model_rise_K_ = (Eigen::Matrix2d::Identity() + a2 * dt + 0.5 * a2 * a2 * dt * dt) * model_rise_K_ + b2 * losses;
  }
  if (housing_loss_floor_W(pfe, ambient_C, share) > 0.0) {
    // The floor binds (housing_loss_floor_W): the housing gets -max(Th - Ta, 0) / Rha in place
    // of Pfe + dP. dP then has no part in the prediction (its column is 0, so its covariance
    // with the temperatures does not grow on a term that is not there), and above the ambient
    // the path to it counts twice.
    // So does g: the floor takes the place of the learned path too.
    a(1, 2) = 0.0;
    g_column = 0.0;
    a(1, 1) = a_model(1, 1);
    u(1) = ambient_C * gha_ch;
    if (x_(1) > ambient_C) {
      a(1, 1) -= gha_ch;
      u(1) += ambient_C * gha_ch;
    }
  }
  // Exact discretisation is not needed at the update rate used (dt far below the winding
  // time constant); a second-order Taylor step keeps it accurate and allocation-free. Only the
  // temperatures' rows of A are nonzero (the loss errors are random walks), so the step
  // I + A dt + A^2 dt^2 / 2 is [F G; 0 I] with F = I + A11 dt + A11^2 dt^2 / 2 and
  // G = E A12, E = I dt + A11 dt^2 / 2 (also the inputs' step: they enter the temperatures'
  // rows alone), and the blocks are all the step needs.
  // The mean moves by the path at the learned conductance (g's column 0: g's part is in the
  // housing's own term); the covariance by the Jacobian, whose g column is the rise g scales.
  const Eigen::Matrix2d a11 = a.topLeftCorner<2, 2>();
  const Eigen::Matrix2d e = Eigen::Matrix2d::Identity() * dt + 0.5 * a11 * dt * dt;
  const Eigen::Matrix2d f = Eigen::Matrix2d::Identity() + a11 * dt + 0.5 * a11 * a11 * dt * dt;
  Eigen::Matrix<double, 2, kStates - 2> a12 = a.topRightCorner<2, kStates - 2>();
  const double before_C = x_(0);
  x_.head<2>() = f * x_.head<2>() + e * (a12 * x_.tail<kStates - 2>()) + e * u;
  a12(1, 2) = g_column;
  const Eigen::Matrix<double, 2, kStates - 2> g_block = e * a12;
  winding_rate_C_per_s_ = dt_s > 0.0 ? (x_(0) - before_C) / dt_s : 0.0;
  // An error the loss states do not carry: at rest no loss runs to teach dP and k, so the cooling
  // path's relative error of the change predicted meanwhile adds up (summed: it is systematic);
  // and the optional unlearned share of how far the model has carried the estimate from where
  // a measurement (or the start) left it.
  if (at_rest) {
    rest_drift_C_ += config_.downtime_error_fraction * std::abs(x_(0) - before_C);
  }
  drift_std_C_ = config_.model_error_fraction * std::abs(x_(0) - anchor_C_) + rest_drift_C_;
  // P = [P11 P12; P12' P22] -> F P11 F' + F P12 G' + G P12' F' + G P22 G', F P12 + G P22, P22.
  const Eigen::Matrix2d p11 = p_.topLeftCorner<2, 2>();
  const Eigen::Matrix<double, 2, kStates - 2> p12 = p_.topRightCorner<2, kStates - 2>();
  const Eigen::Matrix<double, kStates - 2, kStates - 2> p22 = p_.bottomRightCorner<kStates - 2, kStates - 2>();
  const Eigen::Matrix<double, 2, kStates - 2> p12_next = f * p12 + g_block * p22;
  const Eigen::Matrix2d fp12g = f * p12 * g_block.transpose();
  p_.topLeftCorner<2, 2>() = f * p11 * f.transpose() + fp12g + fp12g.transpose() + g_block * p22 * g_block.transpose();
  p_.topRightCorner<2, kStates - 2>() = p12_next;
  p_.bottomLeftCorner<kStates - 2, 2>() = p12_next.transpose();
  // The process noise, on the diagonal.
  p_(0, 0) += config_.winding_process_std_C_per_sqrt_s * config_.winding_process_std_C_per_sqrt_s * dt;
  p_(1, 1) += config_.housing_process_std_C_per_sqrt_s * config_.housing_process_std_C_per_sqrt_s * dt;
  p_(2, 2) += config_.loss_error_process_std_W_per_sqrt_s * config_.loss_error_process_std_W_per_sqrt_s * dt;
  p_(3, 3) += config_.loss_scale_process_std_per_sqrt_s * config_.loss_scale_process_std_per_sqrt_s * dt;
  if (config_.initial_cooling_scale_std > 0.0) {  // (a prior of 0: g not learned, whatever its walk)
    p_(4, 4) += config_.cooling_scale_process_std_per_sqrt_s * config_.cooling_scale_process_std_per_sqrt_s * dt;
  }
  // A loss error unobserved for long (the motor idle: no copper loss to show k) must not
  // become less certain than the commissioning made it: the random walks stop at their priors.
  cap_variance(2, config_.initial_loss_error_std_W * config_.initial_loss_error_std_W);
  cap_variance(3, config_.initial_loss_scale_std * config_.initial_loss_scale_std);
  cap_variance(4, config_.initial_cooling_scale_std * config_.initial_cooling_scale_std);
  since_measurement_s_ += dt_s;
  clock_s_ += dt_s;
  history_C_[history_next_] = x_(0) - history_offset_C_;
  history_s_[history_next_] = clock_s_;
  history_next_ = (history_next_ + 1) % kHistory;
  history_size_ = std::min(history_size_ + 1, kHistory);
}

void ThermalObserver::restart_history() {
  history_offset_C_ = 0.0;
  history_C_[0] = x_(0);
  history_s_[0] = clock_s_;
  history_next_ = 1;
  history_size_ = 1;
}

std::size_t ThermalObserver::history_oldest() const noexcept {
  return (history_next_ + kHistory - history_size_) % kHistory;
}

double ThermalObserver::winding_at_age_C(double age_s) const {
  // Linear between the two updates around the wanted time; the oldest kept value beyond
  // them (the measurement's time precedes the history: a long event, or one right after a
  // restart), the present state when there is none. The kept times increase from
  // the oldest (n = 0) to the newest: a binary search bounds the work at log2(kHistory) steps.
  if (!(age_s > 0.0) || history_size_ == 0) {
    return x_(0);
  }
  const double wanted = clock_s_ - age_s;
  const std::size_t oldest = history_oldest();
  auto at = [&](std::size_t n) { return (oldest + n) % kHistory; };
  if (wanted <= history_s_[at(0)]) {
    return history_C_[at(0)] + history_offset_C_;
  }
  if (wanted >= history_s_[at(history_size_ - 1)]) {
    return x_(0);  // after the last update (the state has not moved since)
  }
  std::size_t lo = 0;                  // history_s_[at(lo)] < wanted
  std::size_t hi = history_size_ - 1;  // history_s_[at(hi)] >= wanted
  while (hi - lo > 1) {
    const std::size_t mid = lo + (hi - lo) / 2;
    if (history_s_[at(mid)] < wanted) {
      lo = mid;
    } else {
      hi = mid;
    }
  }
  const double t0 = history_s_[at(lo)];
  const double t1 = history_s_[at(hi)];
  const double f = t1 > t0 ? (wanted - t0) / (t1 - t0) : 1.0;
  return history_C_[at(lo)] + f * (history_C_[at(hi)] - history_C_[at(lo)]) + history_offset_C_;
}

bool ThermalObserver::update_resistance(double rs_ohm, double rs_std_ohm, double systematic_std_ohm,
                                        double age_s, double from_age_s, double to_age_s,
                                        const BusSlopeTerm& bus_slope) {
  restore_referable_ = false;  // a measurement holds the state from here on, not the downtime's cooling
  // Measurement of the winding temperature through Eq. 1; its variance from the resistance's.
  // It belongs to a moment age_s ago: carried to now by the change the filter predicted since
  // then (the measurement's innovation is against the estimate of its own time). Under a
  // heavy load the winding warms by a noticeable fraction of a degree over an event.
  double then_C = 0.0;
  if (from_age_s > to_age_s && std::isfinite(from_age_s) && std::isfinite(to_age_s) &&
      history_size_ > 0 && from_age_s <= clock_s_ - history_s_[history_oldest()]) {
    // A line through two earlier times (EventEstimate::measured_from_s): compared with the same
    // line through the filter's trajectory, whose warming slows as the winding's does. Only
    // where the history reaches back to both: a value clamped to the oldest kept would bend
    // the line's slope, and the extrapolation multiplies that.
    const double from_C = winding_at_age_C(from_age_s);
    then_C = from_C + (winding_at_age_C(to_age_s) - from_C) * (from_age_s - age_s) / (from_age_s - to_age_s);
  } else {
    then_C = winding_at_age_C(age_s);
  }
  const double z = temperature_from_resistance_C(rs_ohm) + (x_(0) - then_C);
  const double dt_dr =
      temperature_per_resistance_C_per_ohm(winding_rs0_ohm(), calibration_.t0_C, config_.conductor_inferred_zero_C);
  const double r = std::pow(rs_std_ohm * dt_dr, 2) + std::pow(config_.measurement_floor_std_C, 2);
  Eigen::Matrix<double, 1, kStates> h = Eigen::Matrix<double, 1, kStates>::Zero();
  h(0) = 1.0;
  // A measurement without a finite value and error bar is no measurement (NaN compares false,
  // so it would otherwise pass the gate and poison the state).
  if (!std::isfinite(z) || !std::isfinite(r) || !(rs_std_ohm >= 0.0)) {
    return false;
  }
  // The bus slope's error moves the measured temperature by dT/dRs times its resistance.
  if (bus_slope.usable()) {
    refer_bus_slope(bus_slope);
    h(kBusSlopeState) = bus_slope.sensitivity_ohm * dt_dr;
  }
  // The prediction of the measurement: the winding, and the bus slope's share.
  const double predicted_C = (h * x_)(0, 0);
  if (gated_in_row_ >= kReanchorAfterGated && reanchor_consistent(z, r)) {
    // Several gated measurements in a row that agree with each other (and with this one) mean
    // the state is wrong, not the measurements (e.g. an outlier took the first, ungated
    // place): forget the temperatures' certainty, as at a start from a guess, and take this
    // one ungated. Gated measurements that scatter are wild ones: they stay gated.
    const double u = config_.unknown_initial_std_C * config_.unknown_initial_std_C;
    p_(0, 0) = p_(1, 1) = u;
    p_(0, 1) = p_(1, 0) = 0.95 * u;
    p_.topRightCorner<2, kStates - 2>().setZero();
    p_.bottomLeftCorner<kStates - 2, 2>().setZero();
    shared_error_C_ = 0.0;
    anchored_ = false;
  }
  // The model error accumulated since the last measurement belongs to the prediction's
  // variance (it is what the measurement corrects).
  const double drift_var = drift_std_C_ * drift_std_C_;
  const double s = (h * p_ * h.transpose())(0, 0) + drift_var + r;
  // Before the first measurement of a start from a guess (or a restored prediction) there is
  // no trustworthy prediction to gate against.
  if (anchored_ && !(std::abs(z - predicted_C) <= config_.gate_sigma * std::sqrt(s))) {
    if (gated_in_row_ >= 2 * kReanchorAfterGated) {
      gated_in_row_ = 0;  // a window of scattered ones: start the count again
      gated_sum_C_ = gated_sq_sum_C2_ = gated_r_sum_C2_ = 0.0;
    }
    ++gated_in_row_;
    gated_sum_C_ += z;
    gated_sq_sum_C2_ += z * z;
    gated_r_sum_C2_ += r;
    return false;
  }
  gated_in_row_ = 0;
  gated_sum_C_ = gated_sq_sum_C2_ = gated_r_sum_C2_ = 0.0;
  p_(0, 0) += drift_var;
  drift_std_C_ = 0.0;
  rest_drift_C_ = 0.0;
  const bool anchored_before = anchored_;
  anchored_ = true;
  // Huber's weight (ThermalConfig::huber_sigma): beyond the threshold the measurement's own
  // variance grows until the innovation's standard deviation is |innovation| / huber_sigma, so the
  // state moves as far as it would for a measurement at the threshold, and the covariance
  // shrinks by what such a measurement teaches. Not for a start's first measurement (nothing
  // trustworthy to weigh it against, as for the gate). With the weight w = huber_sigma sqrt(s) /
  // |innovation| in (0, 1] the fused variance is s / w and the fused measurement variance
  // r + s / w - s; both are written through w so that nothing divides by a weight near zero.
  const double innovation_C = z - predicted_C;
  double w = 1.0;
  if (anchored_before && std::abs(innovation_C) > config_.huber_sigma * std::sqrt(s)) {
    w = config_.huber_sigma * std::sqrt(s) / std::abs(innovation_C);
  }
  const Vector g = p_ * h.transpose() / s;  // the plain Kalman gain
  const Vector k = w * g;
  const double before_C = x_(0);
  x_ += k * innovation_C;
  // Joseph form keeps P symmetric and positive: P' = (I - K h) P (I - K h)' + K r_fused K',
  // where K r_fused K' = g (w s - w^2 (s - r)) g' (s - r is the prediction's share of s).
  const Matrix i_kh = Matrix::Identity() - k * h;
  p_ = i_kh * p_ * i_kh.transpose() + g * (w * s - w * w * (s - r)) * g.transpose();
  // The copper loss's scale stays physical: the machine's loss between half and twice the
  // model's (beyond that it is no commissioning, and below -1 the loss would be negative).
  x_(3) = std::clamp(x_(3), kMinLossScale, kMaxLossScale);
  // And the cooling path's: between half and twice the model's.
  x_(4) = std::clamp(x_(4), kMinCoolingScale, kMaxCoolingScale);
  // A model error shared by consecutive measurements is not averaged away: the state carries
  // the share k of this measurement's and (1 - k) of what it carried before. It widens the
  // reported band without changing the gain (which must not trust the next measurement with
  // the same error more).
  const double systematic_C = std::abs(systematic_std_ohm * dt_dr);
  shared_error_C_ = k(0) * (std::isfinite(systematic_C) ? systematic_C : 0.0) + (1.0 - k(0)) * shared_error_C_;
  since_measurement_s_ = 0.0;
  anchor_C_ = x_(0);
  holds_uncalibrated_ = holds_uncalibrated_ || !calibration_.calibrated;
  // The state jumped: the kept trajectory moves with it, so that a later measurement whose
  // time lies before the jump (a held one's recordings, DriveController::hold_estimate) is
  // carried to now by the change the model predicted since then, not by the change since the
  // jump alone.
  history_offset_C_ += x_(0) - before_C;
  return true;
}

void ThermalObserver::cap_variance(int i, double limit) {
  // Scaling row and column i by the same factor keeps P symmetric and positive semi-definite
  // (a congruence), and brings its diagonal element to the limit.
  if (p_(i, i) > limit && limit > 0.0) {
    const double s = std::sqrt(limit / p_(i, i));
    p_.row(i) *= s;
    p_.col(i) *= s;
  }
}

bool ThermalObserver::reanchor_consistent(double z, double r) const {
  // The gated row and this measurement scatter no more than their own errors allow (3 sigma).
  const double n = static_cast<double>(gated_in_row_);
  const double mean = gated_sum_C_ / n;
  const double var = std::max(gated_sq_sum_C2_ / n - mean * mean, 0.0);
  const double own = gated_r_sum_C2_ / n;
  return var <= 9.0 * own && std::abs(z - mean) <= 3.0 * std::sqrt(own + r);
}

double ThermalObserver::uncalibrated_rs0_std_C() const {
  return holds_uncalibrated_ ? rs0_std_C_at(x_(0)) : 0.0;
}

double ThermalObserver::rs0_std_C_at(double temp_C) const {
  // Eq. 1 referred to T0: T = (K + T0) Rs / Rs0 - K, so dT/dRs0 = -(K + T) / Rs0.
  if (calibration_.calibrated) {
    return 0.0;
  }
  // (With a cable, dT/dRs0 = -(K + T) / (Rs0 - Rc) for an error that is Rs0's fraction.)
  const double s = (config_.conductor_inferred_zero_C + temp_C) *
                   (calibration_.rs0_std_fraction * (calibration_.rs0_ohm / winding_rs0_ohm()));
  return std::isfinite(s) ? std::abs(s) : 0.0;
}

double ThermalObserver::reference_std_C() const {
  // Eq. 1 referred to T0: T = (K + T0) Rs / Rs0 - K, so dT/dT0 = Rs / Rs0 = (K + T) / (K + T0)
  // (with a cable, (Rs - Rc) / (Rs0 - Rc): the same ratio). An Rs0 no calibration run measured
  // is the nameplate's at its own reference temperature: its share is rs0_std_fraction's.
  // Beside the sensor's, the share of the model's rise T0 was referred through (Calibration::t0_rise_std_C).
  const double t0_std_C = std::hypot(std::max(config_.reference_std_C, 0.0), std::max(calibration_.t0_rise_std_C, 0.0));
  if (!calibration_.calibrated || !(t0_std_C > 0.0)) {
    return 0.0;
  }
  const double k = config_.conductor_inferred_zero_C;
  const double s = t0_std_C * (k + x_(0)) / (k + calibration_.t0_C);
  return std::isfinite(s) ? std::abs(s) : 0.0;
}

double ThermalObserver::measured_winding_variance_C2() const {
  return std::max(p_(0, 0), 0.0) + drift_std_C_ * drift_std_C_ + shared_error_C_ * shared_error_C_;
}

ThermalEstimate ThermalObserver::estimate() const {
  const double rs0_C = uncalibrated_rs0_std_C();
  const double t0_C = reference_std_C();
  return {x_(0), std::sqrt(measured_winding_variance_C2() + rs0_C * rs0_C + t0_C * t0_C),
          x_(1), x_(2) + x_(3) * last_copper_loss_W_, x_(2), x_(3), std::sqrt(std::max(p_(3, 3), 0.0)),
          since_measurement_s_, x_(4)};
}

bool ThermalObserver::time_to_limit_s(double limit_C, double copper_current_sq_A2,
                                      double omega_m_rad_s, double ambient_C, double* out_s,
                                      double copper_loss_per_housing_C) const {
  if (x_(0) >= limit_C) {
    *out_s = 0.0;
    return true;
  }
  // Losses held constant; copper loss taken at the limit temperature (resistance rises with
  // temperature, so this errs towards a shorter time).
  const double pcu_copper = 1.5 * winding_resistance_at_C(limit_C) * copper_current_sq_A2 * (1.0 + x_(3));
  const double pfe = iron_loss_W(omega_m_rad_s);
  const double gwh = 1.0 / config_.winding_to_housing_K_W;
  // The learned path, at the given speed's share of it (a shaft fan's).
  const double share = housing_cooling_share(config_, omega_m_rad_s);
  const double gha = (1.0 + x_(4)) * share / config_.housing_to_ambient_K_W;
  // The torque held, the copper loss grows with the housing's (and so the magnets')
  // temperature as the flux falls: linearised, gamma W more per kelvin of housing above its
  // present temperature. It stays below half the housing's conductance to ambient, so the
  // network keeps a steady state (a loss growing faster than the housing sheds it would run
  // away; no machine's magnets come near: 1-2 W/K against 8 W/K on the reference).
  const double gamma = std::clamp(copper_loss_per_housing_C * pcu_copper, 0.0, 0.5 * gha);
  const double pcu = pcu_copper;
  // d/dt (Tw, Th) = A (Tw, Th) + u, A = [a00 a01; a10 a11] with a00 = -p, a01 = p + gamma/Cw,
  // a10 = q, a11 = -(q + r) (p = gwh/Cw, q = gwh/Ch, r = gha/Ch, all > 0).
  const double p = gwh / config_.winding_capacity_J_K;
  const double q = gwh / config_.housing_capacity_J_K;
  const double r = gha / config_.housing_capacity_J_K;
  const double a00 = -p;
  const double a01 = p + gamma / config_.winding_capacity_J_K;
  const double a10 = q;
  const double a11 = -(q + r);
  const double u0 = (pcu - gamma * x_(1)) / config_.winding_capacity_J_K;
  const double u1 = (pfe + x_(2) + housing_loss_floor_W(pfe, ambient_C, share) + gha * ambient_C) / config_.housing_capacity_J_K;
  const double det = a00 * a11 - a01 * a10;  // p r - q gamma / Cw > 0 by the clamp
  // Steady state: A x_ss + u = 0.
  const double tw_ss = (a01 * u1 - a11 * u0) / det;
  const double th_ss = (a10 * u0 - a00 * u1) / det;
  if (tw_ss <= limit_C) {
    return false;
  }
  // x(t) = x_ss + V exp(L t) V^-1 (x0 - x_ss); bisection on t. The eigenvalues are real,
  // negative and distinct (the discriminant (a00 - a11)^2 + 4 a01 a10 > 0, the determinant
  // > 0), in closed form: the larger in magnitude from the sum (no cancellation), the other
  // from the determinant.
  const double trace = a00 + a11;
  const double root = std::sqrt((a00 - a11) * (a00 - a11) + 4.0 * a01 * a10);
  const std::array<double, 2> lambda{0.5 * (trace - root), det / (0.5 * (trace - root))};
  // Eigenvectors (a01, lambda - a00); the winding's row of V is (a01, a01).
  const std::array<double, 2> v1{lambda[0] - a00, lambda[1] - a00};
  const double dw = x_(0) - tw_ss;
  const double dh = x_(1) - th_ss;
  const double det_v = a01 * root;  // a01 (lambda1 - lambda0), without the difference's cancellation
  // c = V^-1 (dw, dh); the winding's temperature is a01 c0 e^(l0 t) + a01 c1 e^(l1 t).
  const std::array<double, 2> pc{a01 * (v1[1] * dw - a01 * dh) / det_v, a01 * (a01 * dh - v1[0] * dw) / det_v};
  auto winding_at = [&](double t) {
    return tw_ss + pc[0] * std::exp(lambda[0] * t) + pc[1] * std::exp(lambda[1] * t);
  };
  double lo = 0.0;
  double hi = 10.0 / std::min(std::abs(lambda[0]), std::abs(lambda[1]));
  if (winding_at(hi) < limit_C) {
    return false;
  }
  for (int iteration = 0; iteration < 60; ++iteration) {
    const double mid = 0.5 * (lo + hi);
    (winding_at(mid) < limit_C ? lo : hi) = mid;
  }
  *out_s = hi / config_.time_scale;
  return true;
}

double housing_cooling_share(const ThermalModelConfig& c, double omega_m_rad_s) {
  return math::shaft_fan_share(omega_m_rad_s, c.fan_speed_rad_s, c.fan_standstill_share, c.fan_exponent);
}

double thermal_model_fastest_time_constant_s(const ThermalModelConfig& c) {
  // The larger eigenvalue in magnitude of the network's 2x2 matrix (system_matrix's upper left
  // block), real and negative: (|trace| + sqrt(trace^2 - 4 det)) / 2.
  const double gwh = 1.0 / c.winding_to_housing_K_W;
  // The path at its largest share (a shaft fan's at kFanSpeedSpan times its speed; 1 without).
  const double gha = housing_cooling_share(c, math::kFanSpeedSpan * c.fan_speed_rad_s) / c.housing_to_ambient_K_W;
  const double a00 = gwh / c.winding_capacity_J_K;
  const double a11 = (gwh + gha) / c.housing_capacity_J_K;
  const double det = a00 * (gha / c.housing_capacity_J_K);
  const double trace = a00 + a11;
  const double fastest = 0.5 * (trace + std::sqrt(std::max(trace * trace - 4.0 * det, 0.0)));
  return 1.0 / fastest;
}

namespace {
// Linear from max_current_A at start_C to min_current_A at limit_C and beyond.
DeratingResult derate_linear(const DeratingConfig& config, double temp_C, double start_C, double limit_C) {
  if (!std::isfinite(temp_C)) {
    return {config.min_current_A, true};  // no number to trust: the floor, never a NaN limit
  }
  if (temp_C <= start_C) {
    return {config.max_current_A, false};
  }
  const double fraction = std::clamp((limit_C - temp_C) / (limit_C - start_C), 0.0, 1.0);
  return {config.min_current_A + fraction * (config.max_current_A - config.min_current_A), true};
}
}  // namespace

DeratingResult derate(const DeratingConfig& config, const ThermalEstimate& e) {
  const double upper = e.winding_C + config.confidence_sigma * e.winding_std_C;
  return derate_linear(config, upper, config.derate_start_C, config.limit_C);
}

DeratingResult derate_magnet(const DeratingConfig& config, double magnet_C) {
  return derate_linear(config, magnet_C, config.magnet_start_C, config.magnet_limit_C);
}

}  // namespace pmsm::core
