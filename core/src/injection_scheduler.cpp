#include "pmsm/core/injection_scheduler.hpp"
#include "pmsm/core/window.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "pmsm/core/injection.hpp"

namespace pmsm::core {

std::string_view to_string(InjectionMethod m) {
  switch (m) {
    case InjectionMethod::kNone: return "none";
    case InjectionMethod::kFixedMagnitude: return "fixed-magnitude";
    case InjectionMethod::kFixedAngle: return "fixed-angle";
    case InjectionMethod::kDc: return "dc";
  }
  return "?";
}

std::string_view to_string(Separation s) {
  return s == Separation::kBipolar ? "bipolar" : "unipolar";
}

std::string_view to_string(EventOutcome o) {
  switch (o) {
    case EventOutcome::kPublished: return "published";
    case EventOutcome::kNoAcceptedPairs: return "no_accepted_pairs";
    case EventOutcome::kNoFit: return "no_fit";
    case EventOutcome::kImplausible: return "implausible";
    case EventOutcome::kAborted: return "aborted";
  }
  return "?";
}

std::string_view to_string(PairOutcome o) {
  switch (o) {
    case PairOutcome::kAccepted: return "accepted";
    case PairOutcome::kRejectedSpeedChange: return "rejected_speed_change";
    case PairOutcome::kRejectedLoadChange: return "rejected_load_change";
    case PairOutcome::kRejectedResidual: return "rejected_residual";
    case PairOutcome::kRejectedVoltageHeadroom: return "rejected_voltage_headroom";
    case PairOutcome::kRejectedCurrentLimit: return "rejected_current_limit";
    case PairOutcome::kRejectedImplausible: return "rejected_implausible";
    case PairOutcome::kRejectedVoltageSaturation: return "rejected_voltage_saturation";
    case PairOutcome::kRejectedIllConditioned: return "rejected_ill_conditioned";
    case PairOutcome::kAborted: return "aborted";
    case PairOutcome::kSkippedTorqueDisturbance: return "skipped_torque_disturbance";
    case PairOutcome::kCount: break;
  }
  return "?";
}

bool pair_judged(PairOutcome o) noexcept {
  switch (o) {
    case PairOutcome::kAccepted:
    case PairOutcome::kRejectedSpeedChange:
    case PairOutcome::kRejectedLoadChange:
    case PairOutcome::kRejectedResidual:
    case PairOutcome::kRejectedImplausible:
    case PairOutcome::kRejectedVoltageSaturation:
    case PairOutcome::kRejectedIllConditioned:
      return true;
    case PairOutcome::kRejectedVoltageHeadroom:
    case PairOutcome::kRejectedCurrentLimit:
    case PairOutcome::kAborted:
    case PairOutcome::kSkippedTorqueDisturbance:
    case PairOutcome::kCount:
      return false;
  }
  return false;
}

std::string_view to_string(AbortCause c) {
  switch (c) {
    case AbortCause::kNone: return "none";
    case AbortCause::kDisabled: return "disabled";
    case AbortCause::kMotoringNeedsVoltage: return "motoring_needs_voltage";
    case AbortCause::kSpeedLost: return "speed_lost";
    case AbortCause::kCurrentLimit: return "current_limit";
    case AbortCause::kCount: break;
  }
  return "?";
}

namespace {
// u = (iq / current limit)^2, the saturation model's variable.
double saturation_variable(double iq_A, double limit_A) {
  const double x = limit_A > 0.0 ? iq_A / limit_A : 0.0;
  return std::min(x * x, 1.44);  // a quadratic curve says nothing far beyond 1.2 x the limit
}

// The commissioned map's points: lq_map where it has any, else lq_rated_H at the rated current.
LqMap commissioned_map(const InjectionConfig& c) {
  if (c.lq_map.points > 0) {
    return c.lq_map;
  }
  LqMap m;
  if (c.lq_rated_H > 0.0 && c.rated_current_A > 0.0) {
    m.current_A[0] = c.rated_current_A;
    m.secant_H[0] = c.lq_rated_H;
    m.points = 1;
  }
  return m;
}
}  // namespace

LqShape::LqShape(const InjectionConfig& c) : lq_H_(c.lq_H), limit_A_(c.current_limit_A) {
  // The secant lq_H - b0 s(u) through (0, 0) and the map's points; b0 makes s equal u at the last
  // point. u uncapped here: the cap bounds how far the curve is extrapolated, not where the
  // map's points lie.
  const LqMap m = commissioned_map(c);
  if (m.points <= 0 || m.points > LqMap::kMaxPoints || !(limit_A_ > 0.0) || !std::isfinite(limit_A_)) {
    return;
  }
  const auto n = static_cast<std::size_t>(m.points);
  // The loader refuses anything else (controller_config.cpp); a map built in code that is not a
  // map (NaN, currents not ascending, a secant above lq_H) is one Lq, not a curve through it.
  for (std::size_t k = 0; k < n; ++k) {
    const bool ascending = m.current_A[k] > (k == 0 ? 0.0 : m.current_A[k - 1]);
    if (!ascending || !std::isfinite(m.current_A[k]) || !(m.secant_H[k] > 0.0 && m.secant_H[k] <= c.lq_H)) {
      return;
    }
  }
  const double x_last = m.current_A[n - 1] / limit_A_;
  const double u_last = x_last * x_last;
  const double d_last = c.lq_H - m.secant_H[n - 1];
  if (!(u_last > 0.0) || !(d_last > 0.0)) {
    return;  // no saturation at the map's end: one Lq (saturation only lowers the secant)
  }
  b0_H_ = d_last / u_last;
  if (n == 1) {
    return;  // one point: the quadratic s = u, through it
  }
  for (std::size_t k = 0; k < n; ++k) {
    const double x = m.current_A[k] / limit_A_;
    u_[k + 1] = x * x;
    s_[k + 1] = (c.lq_H - m.secant_H[k]) / b0_H_;
  }
  nodes_ = m.points;
  // Each segment's chord slope, then the slope at each point: the parabola through it and its
  // neighbours (one-sided at the ends), limited to [0, 3 x the smaller chord] where the chords
  // agree in sign and 0 at a turn (Fritsch-Carlson: no overshoot between the points).
  std::array<double, LqMap::kMaxPoints> width{};
  std::array<double, LqMap::kMaxPoints> chord{};
  for (std::size_t k = 0; k < n; ++k) {
    width[k] = u_[k + 1] - u_[k];
    chord[k] = (s_[k + 1] - s_[k]) / width[k];
  }
  auto limited = [](double slope, double a, double b) {
    if (a * b <= 0.0 || slope * a <= 0.0) {
      return 0.0;
    }
    const double bound = 3.0 * std::min(std::abs(a), std::abs(b));
    return std::copysign(std::min(std::abs(slope), bound), a);
  };
  slope_[0] = limited(((2.0 * width[0] + width[1]) * chord[0] - width[0] * chord[1]) / (width[0] + width[1]),
                      chord[0], chord[0]);
  for (std::size_t k = 1; k < n; ++k) {
    slope_[k] = limited((width[k - 1] * chord[k] + width[k] * chord[k - 1]) / (width[k - 1] + width[k]),
                        chord[k - 1], chord[k]);
  }
  slope_[n] = limited(((2.0 * width[n - 1] + width[n - 2]) * chord[n - 1] - width[n - 1] * chord[n - 2]) /
                          (width[n - 1] + width[n - 2]),
                      chord[n - 1], chord[n - 1]);
}

LqShape::At LqShape::at(double iq_A) const {
  const double u = saturation_variable(iq_A, limit_A_);
  if (nodes_ == 0) {
    return {u, 3.0 * u};  // psi = (a - b u) iq: d psi / d iq = a - 3 b u
  }
  const auto n = static_cast<std::size_t>(nodes_);
  if (u >= u_[n]) {  // beyond the map: the straight line along its last slope
    const double s = s_[n] + slope_[n] * (u - u_[n]);
    return {s, s + 2.0 * u * slope_[n]};
  }
  std::size_t k = 1;  // the segment [u_{k-1}, u_k] holding u
  while (k < n && u > u_[k]) {
    ++k;
  }
  // The cubic Hermite segment and its derivative, t along it.
  const double w = u_[k] - u_[k - 1];
  const double t = (u - u_[k - 1]) / w;
  const double t2 = t * t;
  const double t3 = t2 * t;
  const double s = (2.0 * t3 - 3.0 * t2 + 1.0) * s_[k - 1] + (t3 - 2.0 * t2 + t) * w * slope_[k - 1] +
                   (3.0 * t2 - 2.0 * t3) * s_[k] + (t3 - t2) * w * slope_[k];
  const double ds_du = 6.0 * (t2 - t) / w * (s_[k - 1] - s_[k]) + (3.0 * t2 - 4.0 * t + 1.0) * slope_[k - 1] +
                       (3.0 * t2 - 2.0 * t) * slope_[k];
  return {s, s + 2.0 * u * ds_du};
}

double commissioned_lq_saturation_H(const InjectionConfig& c) {
  return LqShape(c).b0_H();
}

InjectionScheduler::InjectionScheduler(const InjectionConfig& config, double period_s,
                                       std::size_t capacity)
    : config_(config),
      period_s_(period_s),
      recorder_(capacity),
      next_event_s_(config.first_event_s),
      vx_V_(config.vx_initial_V),
      vx_var_(config.vx_initial_std_V * config.vx_initial_std_V),
      vx_slope_var_(config.vx_bus_slope_std * config.vx_bus_slope_std),
      lq_H_(config.lq_H),
      lq_shape_(config),
      lq_b_H_(config.learn_lq ? 0.0 : lq_shape_.b0_H()),  // (see InjectionConfig::lq_rated_H)
      recorder_capacity_(capacity) {
  const double a_std = config.lq_initial_std_fraction * config.lq_H;
  const double b_std = config.lq_saturation_std_fraction * config.lq_H;
  // (Not on a machine configured as salient: see InjectionConfig::lq_angle_std_rad.)
  const double c_std = config.max_torque_disturbance_Nm > 0.0 ? 0.0 : config.lq_angle_std_rad * config.flux_linkage_Wb;
  lq_p_[0][0] = a_std * a_std;
  lq_p_[1][1] = b_std * b_std;
  lq_p_[2][2] = c_std * c_std;
  // The window constants the budget needs at every pair start are computed here, once, not
  // in the first control period that needs them.
  (void)window_constants(config.window);
}

bool InjectionScheduler::plausible(double rs_ohm, double margin_ohm) const {
  return rs_ohm >= config_.rs_min_ohm - margin_ohm && rs_ohm <= config_.rs_max_ohm + margin_ohm;
}

FitOptions InjectionScheduler::fit_options(bool fit_vx) const {
  FitOptions o;
  o.fit_vx = fit_vx && config_.fit_dead_time;
  o.fixed_vx_V = config_.fit_dead_time ? vx_V_ : 0.0;
  o.fit_ld = config_.fit_inductance;
  return o;
}

void InjectionScheduler::set_config(const InjectionConfig& config) {
  // (The saturation curve's shape stays: the motor's flux map and current limit are the same in
  // every configuration the drive switches between, DriveConfig::derive_from_motor.)
  config_ = config;
  phase_ = SchedulerPhase::kIdle;
  in_event_ = false;
  listening_ = false;
  recording_ = 0;
  retry_at_rest_ = false;  // (a calibration's start or end: its own timing)
  rest_since_s_ = -1.0;
  last_event_refused_ = false;  // (the generator runs on: its sequence depends on nothing else)
}

double InjectionScheduler::edge_value(double elapsed_s) const {
  // The rising half of the window: B(tn) with tn from -Tw to 0.
  const double tn = std::clamp(elapsed_s, 0.0, config_.tw_s) - config_.tw_s;
  return window_value(config_.window, tn, config_.tw_s);
}

double InjectionScheduler::level_for(int recording) const {
  return recording == 1 ? level1_ : level2_;
}

double InjectionScheduler::delta_theta(double needed_rad, double omega_e_rad_s) const {
  // dTheta = 2 pi (electrical harmonics) or 2 pi p (mechanical), times the smallest whole
  // number that leaves room for recording 1 and the transition. Mechanical only where a
  // mechanical turn is quick enough: a 22-pole-pair rotary table creeping at 2-3 rad/s spanned
  // 2-3 s a pair, four estimates in 26 s with load changes inside pairs (1.58-1.74 / 3.48-4.37 C);
  // with whole electrical turns (two there, 0.19-0.29 s), 0.55-0.63 / 1.32-1.60 C, and the
  // magnet still measured (docs/accuracy.md, ninth round, d).
  const bool mechanical = config_.mechanical_harmonics &&
                          std::abs(omega_e_rad_s) >= config_.mechanical_harmonics_min_speed_rad_s * config_.pole_pairs;
  const double unit = mechanical ? kTwoPi * config_.pole_pairs : kTwoPi;
  return unit * std::max(1.0, std::ceil(needed_rad / unit));
}

InjectionScheduler::Budget InjectionScheduler::budget(const SchedulerInput& in, double tw_s,
                                                      double wanted_A) const {
  Budget b;
  const bool bipolar = config_.separation == Separation::kBipolar;
  const double s_uni = config_.unipolar_polarity >= 0 ? 1.0 : -1.0;
  const double limit = std::min(in.current_limit_A, config_.current_limit_A);
  // Torque-neutral pulses (torque_neutral) move iq by up to the budget's torque over Kt, twice
  // that where the flux guard binds: the current and voltage rooms take the motoring point with
  // iq that much further from zero (both polarities' worst case).
  const Dq im = in.motoring_ref_A;
  Dq room_point = im;  // the operating point the current and voltage rooms take
  if (config_.method == InjectionMethod::kFixedMagnitude && torque_neutral_pulses()) {
    const double kt_Nm_per_A = 1.5 * config_.pole_pairs * config_.flux_linkage_Wb;
    room_point.q += std::copysign(2.0 * config_.max_torque_disturbance_Nm / kt_Nm_per_A, im.q);
  }

  // Current: |i_motoring + s F e_d| <= limit for every polarity s the pair uses.
  double f_current = wanted_A;
  const bool turning = config_.method != InjectionMethod::kFixedMagnitude;  // the worst direction counts
  auto current_room = [&](double s) {
    return max_injection_current_for_current_limit_A(limit, room_point.d, room_point.q, s, turning);
  };
  if (bipolar) {
    f_current = std::min({f_current, current_room(1.0), current_room(-1.0)});
  } else {
    f_current = std::min(f_current, current_room(s_uni));
  }

  // Voltage: Eq. 29 at the operating point, for the polarities used.
  InjectionHeadroomInput h;
  h.rs_ohm = config_.rs_nominal_ohm;
  h.ld_H = config_.ld_H;
  // Lq as learned from the pairs (§5.1 of docs/estimator.md), not as commissioned.
  const double lq_H = lq_secant_H(im.q);
  h.lq_H = lq_H;
  h.flux_linkage_Wb = config_.flux_linkage_Wb;
  h.omega_e_rad_s = in.omega_e_rad_s;
  h.id_A = room_point.d;
  h.iq_A = room_point.q;
  h.voltage_limit_V = in.voltage_limit_V - config_.headroom_margin_V;
  h.tw_s = tw_s;
  h.window = config_.window;
  if (motoring_voltage_time_s_ == in.time_s &&
      std::isfinite(motoring_voltage_V_.d + motoring_voltage_V_.q + motoring_voltage_mean_sq_V2_)) {
    // The machine's voltage at the motoring point is what the current loop commands there, not
    // Eq. 3 on the commissioned model: that leaves out the bridge's uncompensated error, the
    // EMF constant's and the inductances' commissioning errors, and the flux the stator's load
    // takes from the magnets. On a 15 mH blower those added up to more than the margin kept
    // free, and 225 of 229 pairs hit the limit they had been sized to miss
    // (docs/estimator.md section 2). The mean command, lengthened by twice its spread about
    // the mean: a pair records for turns and meets every peak of the machine's own ripple, the
    // EMF harmonics' (a sinusoid's peak is 1.41 of its standard deviation) and the noise's,
    // which the margin does not count. The model keeps what the measurement cannot give: the
    // pulse's own voltage, and the torque-neutral pulses' move of the operating point.
    const Dq& m = motoring_voltage_V_;
    const double mean_sq = m.d * m.d + m.q * m.q;
    const double spread = std::sqrt(std::max(motoring_voltage_mean_sq_V2_ - mean_sq, 0.0));
    const double scale = mean_sq > 0.0 ? 1.0 + 2.0 * spread / std::sqrt(mean_sq) : 1.0;
    InjectionHeadroomInput at_motoring = h;
    at_motoring.id_A = im.d;
    at_motoring.iq_A = im.q;
    const Dq model = motoring_voltage(at_motoring);
    h.motoring_voltage_error_V = {scale * m.d - model.d, scale * m.q - model.q};
  }
  double f_voltage = wanted_A;
  const bool any_direction = config_.method != InjectionMethod::kFixedMagnitude;
  if (bipolar || any_direction) {
    f_voltage = std::min({f_voltage, max_injection_current_at_operating_point_A(h, 1.0),
                          max_injection_current_at_operating_point_A(h, -1.0)});
  } else {
    f_voltage = std::min(f_voltage, max_injection_current_at_operating_point_A(h, s_uni));
  }

  // Torque: reluctance torque 3/2 p |Ld - Lq| F |iq| within the budget (salient machines).
  const double torque_room =
      max_injection_current_for_torque_A(config_.max_torque_disturbance_Nm, config_.pole_pairs, config_.ld_H, lq_H, im.q);
  const bool torque_budget = std::isfinite(torque_room);
  const double f_torque = std::min(wanted_A, torque_room);

  b.f_A = std::max(0.0, std::min({f_current, f_voltage, f_torque}));
  if (b.f_A < config_.f_min_A && f_voltage < f_current && config_.field_weakening_pairs &&
      config_.method == InjectionMethod::kFixedMagnitude &&
      std::abs(in.omega_e_rad_s) >= config_.min_speed_for_angle_rad_s) {
    // The voltage is what stops the configured pair: try two levels that both weaken the
    // field. Upper level: inside the current limit, the voltage range and the torque budget;
    // lower level: off the voltage limit and out of the zero-current band.
    // An event of field-weakening pairs learns no Vx, so its levels have no purpose there:
    // every pair takes the event's largest F (the resistive signal F - lo is all it has).
    double largest = 0.0;
    for (int k = 0; k < event_level_count(); ++k) {
      largest = std::max(largest, config_.levels[static_cast<std::size_t>(k)]);
    }
    const double fw_wanted = config_.f_A * largest;
    const InjectionCurrentRange range = injection_current_range_at_operating_point_A(h, -1.0);
    const double fw_torque = std::min(fw_wanted, torque_room);
    const double high = std::min({fw_wanted, current_room(-1.0), range.hi_A, fw_torque});
    const double low = std::max(range.lo_A, config_.field_weakening_low_fraction * high);
    if (range.valid && high - low >= config_.f_min_A) {
      b.f_A = high;
      b.low_A = low;
      b.field_weakening = true;
      return b;
    }
  }
  if (b.f_A < config_.f_min_A) {
    // The tightest budget is the reason (the configuration guarantees wanted >= F_min).
    if (torque_budget && f_torque < std::min(f_current, f_voltage)) {
      b.limiting = PairOutcome::kSkippedTorqueDisturbance;
    } else {
      b.limiting = f_current <= f_voltage ? PairOutcome::kRejectedCurrentLimit
                                          : PairOutcome::kRejectedVoltageHeadroom;
    }
  }
  return b;
}

void InjectionScheduler::begin_pair(const SchedulerInput& in) {
  pair_bus_sum_V_ = {};
  pair_bus_periods_ = {};
  time_based_ = std::abs(in.omega_e_rad_s) < config_.min_speed_for_angle_rad_s;
  direction_ = in.omega_e_rad_s >= 0.0 ? 1.0 : -1.0;
  PairFitConfig fit;
  fit.lq_H = lq_secant_H(in.motoring_ref_A.q);
  fit.lq_incremental_H = lq_incremental_H(in.motoring_ref_A.q);
  fit.emf_d_Wb = config_.learn_lq ? emf_d_Wb_ : 0.0;
  pair_lq_ = {};
  pair_lq_.emf_d_Wb = fit.emf_d_Wb;
  pair_lq_.shape = lq_shape_.at(in.motoring_ref_A.q);
  pair_lq_.secant_H = fit.lq_H;
  pair_lq_.incremental_H = fit.lq_incremental_H;
  fit.ld_H = config_.ld_H;
  recorder_.start(fit, time_based_ ? MatchBy::kTime : MatchBy::kAngle, direction_);
  if (listening_) {
    level1_ = 0.0;
    level2_ = 0.0;
  } else if (field_weakening_) {
    level1_ = -fw_low_level_;
    level2_ = -1.0;
  } else if (config_.separation == Separation::kBipolar) {
    level1_ = 1.0;
    level2_ = -1.0;
  } else {
    level1_ = 0.0;
    level2_ = config_.unipolar_polarity >= 0 ? 1.0 : -1.0;
  }
  ramp_count_ = 0;
  recording_ = 0;
  level_from_ = 0.0;
  level_to_ = 0.0;
  phase_start_s_ = in.time_s;

  if (config_.method == InjectionMethod::kFixedAngle && !time_based_) {
    // The pulse is an arc centred on the next theta_F ahead of the rotor, far enough ahead
    // for the window edge to start.
    window_arc_rad_ = std::max(config_.window_arc_rad, std::abs(in.omega_e_rad_s) * config_.tw_s);
    pulse_arc_rad_ = 2.0 * window_arc_rad_ + config_.injection_arc_rad;
    const double half = 0.5 * pulse_arc_rad_;
    const double margin = 4.0 * std::abs(in.omega_e_rad_s) * period_s_;
    // Signed distance (in the direction of rotation) from now to the next theta_F.
    const double now = in.theta_e_rad;
    double centre = now + direction_ * wrap_angle_0_2pi(direction_ * (config_.theta_f_rad - now));
    // Whole turns further until it lies at least half + margin ahead: in closed form, so that
    // the step's cost does not grow with the speed (a loop would not end for a speed of inf).
    const double short_rad = half + margin - direction_ * (centre - now);
    if (short_rad > 0.0 && std::isfinite(short_rad)) {
      centre += direction_ * kTwoPi * std::ceil(short_rad / kTwoPi);
    }
    theta_f_unwrapped_ = centre;
    pulse_start_theta_ = centre - direction_ * half;
    recording_ = 1;
    phase_ = SchedulerPhase::kPulseWait;
    return;
  }

  if (config_.method == InjectionMethod::kDc) {
    // A stator-fixed vector; at the rotor angle now it is theta_F.
    dc_theta_f_rad_ = config_.theta_f_rad;
  }
  // Angle-based recordings span whole electrical turns (so the EMF harmonics average out of
  // the fit as well as cancelling in the difference), at least record_arc_rad and at least
  // record_min_time_s at the present speed.
  const double base_arc = config_.method == InjectionMethod::kDc ? config_.dc_revolutions * kTwoPi
                                                                 : config_.record_arc_rad;
  const double min_time_s = field_weakening_ ? std::max(config_.record_min_time_s, config_.field_weakening_record_min_time_s)
                                            : config_.record_min_time_s;
  const double arc = std::max(base_arc, std::abs(in.omega_e_rad_s) * min_time_s);
  record_arc_rad_ = kTwoPi * std::ceil(arc / kTwoPi - 1e-9);
  const double first = level_for(1);
  if (first != 0.0) {
    level_from_ = 0.0;
    level_to_ = first;
    phase_ = SchedulerPhase::kRampUp;
  } else {
    phase_ = SchedulerPhase::kSettle;
  }
}

// Kept out of line: inlined into injection_current(), it cost a round rotor's injecting step 2
// instructions on the path it never takes, and a salient one's 3 (bench/step-cost.sh).
[[gnu::noinline]] Dq InjectionScheduler::torque_neutral(Dq injection_A, const Dq& motoring_A) const {
  // A d-axis pulse on a salient machine changes the torque 3/2 p iq (psi + (Ld - Lq) id) by its
  // reluctance part, with opposite signs in a bipolar pair's two recordings. Left alone, the
  // speed loop answers it late and in part, the shaft's speed moves between the recordings,
  // and the shaft feels the pulse. Here the q-current moves with the pulse instead, so that
  // iq (psi + (Ld - Lq) id) stays what the motoring point asks: iq' = iq flux0 / flux1, with
  // the commissioned Ld and the learned secant Lq. The change is about the torque budget over
  // Kt, at most twice that (the budget bounds F by the uncompensated torque, which it still
  // does: what is left is the saliency model's error; budget() counts the change in the
  // current and voltage rooms), and the fit models its d-axis voltage through
  // Lq d(w iq) as it does the speed loop's answer (docs/estimator.md section 2). Only on a
  // machine configured as salient (a torque budget), and only where both fluxes stay above
  // half the magnet's (as the load-change guard's range). The caller asks for the first.
  // Lq is the pair's, drawn at its start (begin_pair): the motoring iq moves little within a
  // pair, and the saturation curve's evaluation stays out of the injecting steps.
  double flux_0_Wb = 0.0;
  double flux_1_Wb = 0.0;
  if (salient_fluxes(config_.ld_H - pair_lq_.secant_H, motoring_A.d, motoring_A.d + injection_A.d, flux_0_Wb,
                     flux_1_Wb)) {
    injection_A.q += motoring_A.q * (flux_0_Wb - flux_1_Wb) / flux_1_Wb;
  }
  return injection_A;
}

bool InjectionScheduler::salient_fluxes(double saliency_H, double id_a_A, double id_b_A, double& flux_a_Wb,
                                        double& flux_b_Wb) const {
  const double psi_Wb = config_.flux_linkage_Wb;
  flux_a_Wb = psi_Wb + saliency_H * id_a_A;
  flux_b_Wb = psi_Wb + saliency_H * id_b_A;
  return flux_a_Wb >= 0.5 * psi_Wb && flux_b_Wb >= 0.5 * psi_Wb;
}

Dq InjectionScheduler::injection_current(const SchedulerInput& in) const {
  double level = 0.0;
  double envelope = 1.0;
  switch (phase_) {
    case SchedulerPhase::kRampUp:
    case SchedulerPhase::kRampDown: {
      const double e = edge_value(in.time_s - phase_start_s_);
      level = level_from_ + (level_to_ - level_from_) * e;
      break;
    }
    case SchedulerPhase::kSettle:
    case SchedulerPhase::kRecord1:
    case SchedulerPhase::kWaitArc:
    case SchedulerPhase::kRecord2:
      level = level_to_;
      break;
    case SchedulerPhase::kPulseWait: {
      // Fixed-angle pulse: the envelope follows the rotor angle across the arc.
      const double phi = pulse_phase(in.theta_e_rad);
      const PulseEnvelope env{config_.window, window_arc_rad_, config_.injection_arc_rad};
      envelope = env.value(phi);
      level = level_for(recording_);
      break;
    }
    case SchedulerPhase::kIdle:
    case SchedulerPhase::kFinish:
      return {};
  }
  const double f = level * f_A_ * envelope;
  if (f == 0.0) {
    return {};
  }
  switch (config_.method) {
    case InjectionMethod::kFixedMagnitude:
      // Eqs. 18-19; on a machine configured as salient, holding the torque (asked here: the
      // call costs a round rotor's step 15 instructions).
      if (torque_neutral_pulses()) {
        return torque_neutral(fixed_magnitude_injection_current(f), in.motoring_ref_A);
      }
      return fixed_magnitude_injection_current(f);
    case InjectionMethod::kFixedAngle:
      if (time_based_) {
        return fixed_magnitude_injection_current(f);  // at standstill the arc is the d-axis
      }
      return fixed_angle_injection_current(f, theta_f_unwrapped_, config_.beta, in.theta_e_rad);  // Eqs. 11-12
    case InjectionMethod::kDc:
      return dc_injection_current_rotor(f, dc_theta_f_rad_, in.theta_e_rad);  // Eqs. 6-7
    case InjectionMethod::kNone:
      break;
  }
  return {};
}

void InjectionScheduler::abort(SchedulerOutput& out, const SchedulerInput& in, AbortCause cause) {
  const double jitter = (phase_ != SchedulerPhase::kIdle || in_event_) ? refusal_jitter() : 1.0;  // one refusal
  if (phase_ != SchedulerPhase::kIdle && !listening_) {
    PairResult r;
    r.outcome = PairOutcome::kAborted;
    r.abort_cause = cause;
    r.method = config_.method;
    r.separation = config_.separation;
    r.time_s = in.time_s;
    r.f_A = f_A_;
    r.field_weakening = field_weakening_;
    r.low_level = field_weakening_ ? fw_low_level_ : 0.0;
    r.level_index = level_index_;
    out.completed = r;
    next_event_s_ = std::max(next_event_s_, in.time_s + config_.retry_s);
    delay_next_event(in.time_s, jitter);
    if (cause == AbortCause::kSpeedLost) {
      retry_at_rest_ = true;
      rest_since_s_ = -1.0;
    }
  }
  if (in_event_) {
    // An aborted event yields nothing: a request (a calibration's, an operator's) waits the
    // retry delay too, or it would start the next event in the same transient (the shaft
    // reversing under an overhauling load), whose current then eats the voltage and current
    // the drive needs to hold it.
    retry_after_s_ = std::max(retry_after_s_, in.time_s + jitter * config_.retry_s);
    // The event is incomplete: its accepted pairs (if any) are dropped with it, and it says so.
    EventEstimate e;
    e.outcome = EventOutcome::kAborted;
    e.time_s = in.time_s;
    e.pairs = event_pairs_;
    out.estimate = e;
  }
  phase_ = SchedulerPhase::kIdle;
  in_event_ = false;
  listening_ = false;
  out.injection_A = {};
  out.active = false;
  out.phase = phase_;
}

double InjectionScheduler::bus_change_error_ohm(const FitResult& fit) const {
  // Each period's voltage is referred to the reference bus with the bus slope learned so far; a
  // bus that moved between the recordings (a neighbour braking onto a common bus, a supply
  // switched) leaves the recordings referred apart by the slope's error times the move, which
  // the separation takes for resistance: one standard deviation of it, through drs/dVx. It is a
  // part of the pair's error bar and of its event's (finish_event), not a reason to refuse the
  // pair: a single-phase rectifier's bus differs by volts between recordings at every pair, and
  // a table saw refusing them failed its calibration. With the reference motor's dead time
  // commissioned 25 % short and its bus stepping 650 -> 800 V within an event, the events read
  // up to 22 % low before these guards (docs/estimator.md section 4, "A bus that moves within
  // an event").
  if (!config_.fit_dead_time || pair_bus_periods_[0] == 0 || pair_bus_periods_[1] == 0) {
    return 0.0;
  }
  const double move_V = recording_bus_offset_V(0) - recording_bus_offset_V(1);
  const double error = std::abs(fit.drs_dvx) * std::sqrt(std::max(vx_slope_var_, 0.0)) * std::abs(move_V);
  return std::isfinite(error) ? error : 0.0;
}

PairResult InjectionScheduler::finish_pair(const SchedulerInput& in) {
  PairResult r;
  r.method = config_.method;
  r.separation = config_.separation;
  r.time_s = in.time_s;
  r.f_A = f_A_;
  r.field_weakening = field_weakening_;
  r.low_level = field_weakening_ ? fw_low_level_ : 0.0;
  r.level_index = level_index_;
  r.time_based = time_based_;
  const PairConditions c = recorder_.conditions();
  r.conditions = c;
  r.samples = c.samples;
  // The pair on its own, with Vx held at the prior: its guards and its report.
  const FitResult fit = solve_fit(recorder_.sums(), fit_options(false));
  // What the uncertain Lq the pair was fitted with can move its Rs (lq_term): the sample fit's
  // Rs = sum(dId y) / sum(dId^2) to first order.
  const LqTerm lq = lq_term(c);
  LqGradient own;
  if (lq.x_sq_sum_A2 > 0.0) {
    own.add(lq.secant_x_sum_A_V_H / lq.x_sq_sum_A2, lq.incremental_x_sum_A_V_H / lq.x_sq_sum_A2,
            lq.emf_x_sum_A_V_Wb / lq.x_sq_sum_A2, lq.shape);
  }
  const double lq_var_rs = lq_variance(own);
  // Vx's variance at the bus the event has seen so far (its slope's uncertainty away from the
  // reference bus; vx_variance_at).
  const double vx_var_rs = fit.drs_dvx * fit.drs_dvx * (config_.fit_dead_time ? vx_variance_at(event_bus_offset_V()) : 0.0);
  // And what a bus that moved between its recordings can do with the slope's uncertainty.
  const double bus_rs = bus_change_error_ohm(fit);
  r.rs_ohm = fit.rs_ohm;
  r.rs_std_ohm = std::sqrt(fit.var_rs + vx_var_rs + lq_var_rs + bus_rs * bus_rs);
  r.rs_rests_on_vx_guess = !vx_learned_ && vx_var_rs > fit.var_rs;
  r.residual_rms_V = fit.residual_rms_V;
  r.condition = fit.condition;
  r.delta_omega_e_rad_s = c.omega_e_mean_1_rad_s - c.omega_e_mean_2_rad_s;
  // The motoring current is what remains of iq after the injection's own q-axis part, which
  // is zero on average for every method used here (fixed-magnitude, fixed-angle with beta = 0,
  // DC over whole turns), so the means compare directly. The guard below sets apart what the
  // speed loop's answer to a salient machine's reluctance torque adds.
  r.delta_iq_A = c.iq_mean_1_A - c.iq_mean_2_A;

  const double speed_limit = speed_change_limit_rad_s(c);
  if (!fit.valid || fit.condition < config_.min_condition) {
    r.outcome = PairOutcome::kRejectedIllConditioned;
  } else if (c.any_modulation_clipped) {
    r.outcome = PairOutcome::kRejectedVoltageSaturation;
  } else if (!time_based_ && std::abs(r.delta_omega_e_rad_s) > speed_limit) {
    r.outcome = PairOutcome::kRejectedSpeedChange;
  } else if (unexplained_load_change_A(c, r.delta_iq_A) > config_.max_load_change_A) {
    r.outcome = PairOutcome::kRejectedLoadChange;
  } else if (fit.residual_rms_V > config_.max_residual_V) {
    r.outcome = PairOutcome::kRejectedResidual;
  } else if (!plausible(fit.rs_ohm, 3.0 * std::sqrt(vx_var_rs + bus_rs * bus_rs))) {
    // The window widens by what the uncertain inverter voltage can move this pair's Rs (not by
    // the Lq term's: on a DC pulse at speed it is large, and the window would pass anything).
    r.outcome = PairOutcome::kRejectedImplausible;
  } else {
    r.outcome = PairOutcome::kAccepted;
    learn_lq(c, fit, in);
    event_sums_.add(recorder_.sums());
    const auto slot = static_cast<std::size_t>(std::min(event_pairs_, InjectionConfig::kMaxLevels - 1));
    event_pair_sums_[slot] = recorder_.sums();
    event_pair_time_s_[slot] = c.rs_time_s;
    event_bus_error_ohm_ = std::max(event_bus_error_ohm_, bus_rs);
    event_pair_bus_V_[slot] = {recording_bus_offset_V(0), recording_bus_offset_V(1)};
    event_pair_lq_[slot] = lq;
    event_min_f_A_ = event_pairs_ == 0 ? f_A_ : std::min(event_min_f_A_, f_A_);
    event_max_iq_A_ = std::max(event_max_iq_A_, 0.5 * std::abs(c.iq_mean_1_A + c.iq_mean_2_A));
    event_max_speed_ = std::max(event_max_speed_, 0.5 * std::abs(c.omega_e_mean_1_rad_s + c.omega_e_mean_2_rad_s));
    // The event's Rs is a fit over its pairs, each weighing by its information (about the
    // reciprocal of its own variance): the time it belongs to is their weighted mean time.
    // A variance floor of (1 nOhm)^2 keeps a subnormal variance from an infinite weight; a pair
    // without one (not finite, or none) does not place the event in time.
    const double w = fit.var_rs > 0.0 && std::isfinite(fit.var_rs) ? 1.0 / std::max(fit.var_rs, 1e-18) : 0.0;
    event_time_weight_ += w;
    event_time_sum_s_ += w * (c.rs_time_s - event_start_s_);
    event_time_plain_sum_s_ += c.rs_time_s - event_start_s_;
    event_span_sums_s_[0] += w * (c.time_1_s - c.rs_time_s);
    event_span_sums_s_[1] += w * (c.time_2_s - c.rs_time_s);
    event_span_sums_s_[2] += c.time_1_s - c.rs_time_s;
    event_span_sums_s_[3] += c.time_2_s - c.rs_time_s;
    event_field_weakening_ = event_field_weakening_ || field_weakening_;
    // The magnet's EMF constant from the q axis, field-weakening pairs included: each pair
    // measures the Ld its <w id> needs (finish_event; docs/estimator.md §8).
    if (event_q_pairs_ < InjectionConfig::kMaxLevels && !time_based_) {
      event_q_[static_cast<std::size_t>(event_q_pairs_++)] = c;
    }
    ++event_pairs_;
  }
  return r;
}

// (Learning off, the curve keeps its priors: the commissioned lq_H and saturation.)
double InjectionScheduler::lq_secant_H(double iq_A) const {
  return lq_secant_at(lq_shape_.at(iq_A));
}

double InjectionScheduler::lq_incremental_H(double iq_A) const {
  return lq_incremental_at(lq_shape_.at(iq_A));
}

double InjectionScheduler::lq_secant_at(const LqShape::At& shape) const {
  return std::clamp(lq_H_ - lq_b_H_ * shape.s - lq_b2_H_ * shape.s2(), 0.5 * lq_H_, 1.5 * lq_H_);
}

bool InjectionScheduler::saturation_variance_resolved() const {
  const double prior = config_.lq_saturation_std_fraction * config_.lq_H;
  // b's variance given the angle's share c (the Schur complement): whether pairs at two loads
  // have told b apart from a. What c leaves open on top is carried by the variances (lq_variance),
  // not by falling back to the secant: on the 30 mOhm IPM, whose pairs put c at 0 +- 0.026 deg,
  // b's marginal variance stayed above the quarter and the fallback read 20.7 C RMS (1.8 C
  // resolved).
  // Given the bend b2 too, once it is a state: it enters with every (a, b) that keeps the first
  // two anchors' secants (add_bend_prior), which widens b's marginal variance by (s1 + s2)^2
  // var(b2) without telling the slope between them any less well.
  double var_b = lq_p_[1][1];
  const double p22 = lq_p_[2][2];
  const double p33 = lq_p_[3][3];
  const double p12 = lq_p_[1][2];
  const double p13 = lq_p_[1][3];
  const double p23 = lq_p_[2][3];
  // (Both are states only where a rotor-angle check gave c its prior after the bend had entered.
  // A block near singular, c and b2 all but confounded, is conditioned on b2 alone.)
  const double det = p22 * p33 - p23 * p23;
  if (p22 > 0.0 && p33 > 0.0 && det > 1e-9 * p22 * p33) {
    var_b -= (p12 * p12 * p33 - 2.0 * p12 * p13 * p23 + p13 * p13 * p22) / det;
  } else if (p33 > 0.0) {
    var_b -= p13 * p13 / p33;
  } else if (p22 > 0.0) {
    var_b -= p12 * p12 / p22;
  }
  return var_b < 0.25 * prior * prior;
}

double InjectionScheduler::lq_incremental_at(const LqShape::At& shape) const {
  // psi = (a - b s) iq: d psi / d iq = a - b h (3 b u on the quadratic). Until pairs at two
  // loads have resolved b (its variance below a quarter of its prior), a and b are known only
  // in the combination a - b s of the loads seen, and b h would multiply whatever error b
  // took from them: until then the incremental is the secant (which pairs at this load
  // measure) less the commissioned gap b0 (h - s) (which they cannot; 0 where no saturation
  // was commissioned).
  const double secant = lq_secant_at(shape);
  if (!lq_resolved_) {
    return std::clamp(secant - lq_shape_.b0_H() * (shape.h - shape.s), 0.5 * secant, secant);
  }
  return std::clamp(lq_H_ - lq_b_H_ * shape.h - lq_b2_H_ * shape.h2(), 0.5 * secant, 1.5 * secant);
}

double InjectionScheduler::unexplained_load_change_A(const PairConditions& c, double delta_iq_A) const {
  // On a salient machine each pulse's reluctance torque 3/2 p (Ld - Lq) id iq differs between
  // the recordings, and the speed loop answers it with iq: not yet, in part, or fully, when
  // the torque is the same in both recordings, iq2 (psi + (Ld - Lq) id2) = iq1 (psi + (Ld -
  // Lq) id1). Any answer from none to the full one is the injection's own doing, not a load
  // change, and the fit models its d-axis voltage through Lq d(w iq) (docs/estimator.md
  // section 3). The guard judges what lies outside that range. Only on a machine configured as
  // salient (a reluctance-torque budget, as the angle check asks): on a round rotor the
  // commissioned Ld and the learned Lq differ by their errors alone, and a window from them
  // would let load changes through. Without it, or with the fluxes far from the magnet's (a
  // range the model does not hold), the plain |diq|.
  if (!std::isfinite(delta_iq_A)) {
    return std::numeric_limits<double>::infinity();
  }
  if (!(config_.max_torque_disturbance_Nm > 0.0)) {
    return std::abs(delta_iq_A);
  }
  double flux_1_Wb = 0.0;
  double flux_2_Wb = 0.0;
  if (!salient_fluxes(config_.ld_H - lq_secant_H(0.5 * (c.iq_mean_1_A + c.iq_mean_2_A)), c.id_mean_1_A,
                      c.id_mean_2_A, flux_1_Wb, flux_2_Wb)) {
    return std::abs(delta_iq_A);
  }
  const double full_A = c.iq_mean_1_A * (flux_2_Wb - flux_1_Wb) / flux_2_Wb;
  const double lo_A = std::min(0.0, full_A);
  const double hi_A = std::max(0.0, full_A);
  return delta_iq_A < lo_A ? lo_A - delta_iq_A : (delta_iq_A > hi_A ? delta_iq_A - hi_A : 0.0);
}

InjectionScheduler::LqTerm InjectionScheduler::lq_term(const PairConditions& c) const {
  // A salient machine's speed loop answers the injection's reluctance torque with a diq
  // proportional to F, and a speed ramp puts dw into a pair: on the 30 mOhm IPM at speed the
  // incremental term alone is as large as the resistive signal 2 Rs F, and on the salient
  // benchmark a pair fitted with the commissioned Lq (10 % low) read Rs 8 % low
  // (docs/estimator.md section 5.1).
  LqTerm t = pair_lq_;
  t.secant_mean_V_H = c.lq_secant_mean_V_H;
  t.incremental_mean_V_H = c.lq_incremental_mean_V_H;
  t.secant_x_sum_A_V_H = c.lq_secant_x_sum_A_V_H;
  t.incremental_x_sum_A_V_H = c.lq_incremental_x_sum_A_V_H;
  t.emf_mean_V_Wb = c.emf_mean_V_Wb;
  t.emf_x_sum_A_V_Wb = c.emf_x_sum_A_V_Wb;
  t.x_sq_sum_A2 = c.x_sq_sum_A2;
  return t;
}

void InjectionScheduler::set_angle_prior(double delta_rad, double std_rad) {
  if (!config_.learn_lq || config_.max_torque_disturbance_Nm > 0.0 || !std::isfinite(delta_rad) ||
      !(std::isfinite(std_rad) && std_rad >= 0.0)) {
    return;
  }
  const double psi = config_.flux_linkage_Wb;
  emf_d_Wb_ = psi * delta_rad;
  for (std::size_t i = 0; i < kLqStates; ++i) {
    lq_p_[i][2] = 0.0;
    lq_p_[2][i] = 0.0;
  }
  lq_p_[2][2] = psi * std_rad * psi * std_rad;
  lq_resolved_ = saturation_variance_resolved();
  ++learned_version_;
}

std::array<double, 3> InjectionScheduler::lq_change_H(const LqTerm& t) const {
  if (!config_.learn_lq) {
    return {0.0, 0.0, 0.0};  // the commissioned Lq throughout: nothing newer to refit with
  }
  return {lq_secant_at(t.shape) - t.secant_H, lq_incremental_at(t.shape) - t.incremental_H, emf_d_Wb_ - t.emf_d_Wb};
}

void InjectionScheduler::LqGradient::add(double d_secant, double d_incremental, double d_emf, const LqShape::At& shape) {
  // The curve's state (a, b, c, b2): the secant is a - b s - b2 s2 and the incremental
  // a - b h - b2 h2 (an incremental not yet resolved is the secant less the commissioned
  // b0 (h - s), about (b - b0) (h - s) off the true incremental: the same form with b's
  // uncertainty); c enters on its own; b2's variance is 0 until a third anchor (add_bend_prior).
  g[0] += d_secant + d_incremental;
  g[1] -= shape.s * d_secant + shape.h * d_incremental;
  g[2] += d_emf;
  g[3] -= shape.s2() * d_secant + shape.h2() * d_incremental;
}

double InjectionScheduler::lq_variance(const LqGradient& g) const {
  // Learning off, (a, b, c, b2) keep their priors.
  double var = 0.0;
  for (std::size_t i = 0; i < kLqStates; ++i) {
    for (std::size_t j = 0; j < kLqStates; ++j) {
      var += g.g[i] * lq_p_[i][j] * g.g[j];
    }
  }
  return std::isfinite(var) ? std::max(var, 0.0) : 0.0;
}

bool InjectionScheduler::learn_lq(const PairConditions& c, const FitResult& fit, const SchedulerInput& in) {
  if (!config_.learn_lq || time_based_) {
    return false;
  }
  const double w_iq = c.omega_e_iq_mean_A_rad_s;
  const double s_q = lq_shape_.at(c.iq_mean_A).s;  // the secant's shape at the pair's load
  // Over whole turns (Eq. 3, d-axis): Lq <w iq> = Rs <id> + Ld <dId/dt> + Vx <Gd> - <vd>.
  const double vx = config_.fit_dead_time ? vx_V_ : 0.0;
  const double var_vx = config_.fit_dead_time ? vx_variance_at(event_bus_offset_V()) : 0.0;
  // Learn only where the Lq term stands out: at least the configured volts, and at least the
  // known terms it is told apart from (a unipolar pair's Rs <id> and Vx <Gd>; about 0 for a
  // bipolar pair), whose model errors in proportion (the bridge's pattern) the variance below
  // does not carry.
  const double separated = std::abs(fit.rs_ohm * c.id_mean_A) + std::abs(vx * c.gd_mean);
  if (!(std::abs(lq_secant_H(c.iq_mean_A) * w_iq) >= std::max(config_.lq_learning_min_voltage_V, separated))) {
    return false;
  }
  // <Rs id> over the two recordings, 0.5 (Rs(t1) Id1 + Rs(t2) Id2), with the thermal filter's
  // resistance carried to each recording's time by the model's rate. Not the pair's own Rs:
  // that belongs to the pair's time (PairConditions::rs_time_s), which on a motoring point in
  // field weakening lies some 3 recordings' spacings beyond the second, where a warming winding
  // is warmer than the recordings saw; and it carries the pair's noise (2 % of Rs on a
  // field-weakening pair, against the filter's fraction of that). Taken from the pair, a
  // newcomer's salient servo heating at 1100 rad/s learned Lq 0.5 % low and a saturation it
  // does not have (docs/estimator.md section 5.1). The pair's own Rs when the drive gives none
  // (before the filter's first update, and while a calibration runs).
  double rs_id_V = fit.rs_ohm * c.id_mean_A;
  double var_rs_id = c.id_mean_A * c.id_mean_A * fit.var_rs;
  if (std::isfinite(winding_rs_ohm_) && std::isfinite(in.rs_rate_ohm_per_s) && config_.method == InjectionMethod::kFixedMagnitude) {
    // Rs at the recordings' mean time on the matched samples' <id>, and the part that Rs's
    // change between them adds, 0.5 rate ((t1 - tm) Id1 + (t2 - tm) Id2).
    const double rs_mid_ohm = winding_rs_ohm_ + in.rs_rate_ohm_per_s * (0.5 * (c.time_1_s + c.time_2_s) - in.time_s);
    rs_id_V = rs_mid_ohm * c.id_mean_A +
              0.25 * in.rs_rate_ohm_per_s * (c.time_1_s - c.time_2_s) * (c.id_mean_1_A - c.id_mean_2_A);
    // (The filter's error is shared by the pairs until its next fusion; taken here as each
    // pair's own, it lets Lq's variance shrink over it. It is a fraction of a per cent of Rs.)
    var_rs_id = c.id_mean_A * c.id_mean_A * winding_rs_var_ohm2_;
  }
  const double lq =
      (rs_id_V + config_.ld_H * c.did_dt_mean_A_s + vx * c.gd_mean - c.vd_mean_V) / w_iq;
  // Its variance: what the uncertain Vx and Rs move it by, and the noise of <vd> (the pair's
  // residual over its independent samples, about one per filter length).
  const double independent = std::max(1.0, static_cast<double>(c.samples) / 8.0);
  const double var = (c.gd_mean * c.gd_mean * var_vx + var_rs_id +
                      fit.residual_rms_V * fit.residual_rms_V / independent) /
                     (w_iq * w_iq);
  if (!std::isfinite(lq) || !(var > 0.0)) {
    return false;
  }
  // The curve may have moved since the last pair (a prediction step before the gate, so that
  // a state that has become confidently wrong widens until pairs pass again). The angle error
  // does not move (the magnet's flux by a few per cent as it warms: not modelled).
  const double drift = config_.lq_drift_fraction * config_.lq_H;
  lq_p_[0][0] += drift * drift;
  ++learned_version_;  // (and the update below, if the pair passes the gate)
  if (config_.lq_saturation_std_fraction > 0.0) {
    lq_p_[1][1] += drift * drift;  // (without the saturation model b and b2 stay at 0)
    if (lq_bend_active_) {
      lq_p_[3][3] += drift * drift;
    }
  }
  lq_resolved_ = saturation_variance_resolved();
  // Gross outliers (a pair that passed its guards but whose means are off) are left out.
  // The pair measures a - b s_q - b2 s_q^2 - c <w> / <w iq> (<vd> holds c <w>): a Kalman update of
  // (a, b, c, b2) with h = (1, -s_q, -<w> / <w iq>, -s_q^2), <w> over both recordings.
  //
  // The loads that have taught the curve are kept as anchors at least a lever apart in s (twice
  // kLqUnmodelledFraction over b's prior fraction: 0.05 with the default prior and shape, from
  // no load to 22 % of the current limit). A pair within a lever of an anchor is taken at the
  // anchor's s; a pair a lever from every anchor is taken at its own and, if it passes the gate,
  // becomes one. So b learns from the differences between anchors only, never from loads closer
  // together: between such loads b would be the difference of two means over the difference of
  // their s, and a pair's d-axis mean carries half a per cent of Lq that the model does not hold
  // and that does not average out over pairs at one operating point (the bridge's pattern at an
  // event's two levels, a term that grows with speed). Read as saturation across the 0.15 A by
  // which an event's two levels differ in iq (the speed loop's answer to each level's
  // reluctance torque), it drove b to 1.8 mH on a spindle of 0.68 mH (unseen round 17, case a):
  // the secant stood at its 0.5 a clamp at the roughing's load, the roughing's own pairs, which
  // measured 0.68 mH, fell outside the gate, and the winding read 11 C low (docs/estimator.md
  // section 5.1). The prediction takes the pair's own s (the curve as learned), and the pair's
  // variance the part that b's uncertainty puts between its s and the anchor's.
  const double lever = lq_lever();
  int nearest = -1;
  double nearest_ds = std::numeric_limits<double>::infinity();
  for (int k = 0; k < lq_anchor_count_; ++k) {
    const double ds = std::abs(s_q - lq_anchors_[static_cast<std::size_t>(k)]);
    if (ds < nearest_ds) {
      nearest = k;
      nearest_ds = ds;
    }
  }
  const bool at_anchor = nearest >= 0 && (nearest_ds < lever || lq_anchor_count_ == kMaxLqAnchors);
  const double s_used = at_anchor ? lq_anchors_[static_cast<std::size_t>(nearest)] : s_q;
  const double w_mean = 0.5 * (c.omega_e_mean_1_rad_s + c.omega_e_mean_2_rad_s);
  const std::array<double, kLqStates> h{1.0, -s_used, -w_mean / w_iq, -s_used * s_used};
  const double predicted = lq_H_ - lq_b_H_ * s_q - lq_b2_H_ * s_q * s_q + emf_d_Wb_ * h[2];
  // A pair that would be the third anchor is judged and fused with the bend in: a curve that
  // bends misses the straight line through two anchors by more than their variance says (2.7 %
  // of Lq at the middle of a u^2 machine's range), and the pair is what teaches b2. Not where the
  // angle's share c is a state: c's 1 / iq and the bend's s^2 both bend what three loads see (an
  // encoder 0.3 deg off, learned at 5, 30 and 60 A, read 3.5 % high at 60 A with the bend in), and
  // a fourth anchor would need the bend's prior to keep three secants through c's regressor,
  // which depends on each pair's speed. c is never a state on a machine configured as salient,
  // where the incremental Lq matters (docs/estimator.md section 5.1).
  const bool bends = !at_anchor && lq_anchor_count_ == 2 && !lq_bend_active_ && !(lq_p_[2][2] > 0.0) &&
                     config_.lq_saturation_std_fraction > 0.0;
  LqCovariance p = lq_p_;
  if (bends) {
    add_bend_prior(p);
  }
  std::array<double, kLqStates> ph{};  // P h
  double s = var;                      // h P h' + var, and below what (b, b2) put between s_q and s_used
  for (std::size_t i = 0; i < kLqStates; ++i) {
    for (std::size_t j = 0; j < kLqStates; ++j) {
      ph[i] += p[i][j] * h[j];
    }
    s += h[i] * ph[i];
  }
  const double d1 = s_q - s_used;
  const double d2 = s_q * s_q - s_used * s_used;
  s += d1 * d1 * p[1][1] + 2.0 * d1 * d2 * p[1][3] + d2 * d2 * p[3][3];
  if (lq < 0.5 * config_.lq_H || lq > 2.0 * config_.lq_H || !(s > 0.0) || !std::isfinite(h[2]) ||
      !(std::abs(lq - predicted) <= 4.0 * std::sqrt(s))) {
    return false;
  }
  if (!at_anchor) {
    lq_anchors_[static_cast<std::size_t>(lq_anchor_count_++)] = s_q;
  }
  if (bends) {
    lq_bend_active_ = true;
    lq_p_ = p;
  }
  // A pair whose q current idles inside the bridge's ripple band does not teach c: its d-axis
  // mean keeps a per cent or two of Vx that the bipolar recordings cancel only as far as the
  // model of the bridge's zero crossings holds, and c / iq, whose lever is largest there, took
  // it for the angle. On the 14-pole servo of round 7 (idling at 0.6 A, band 1.25 A, Vx 6.5 V)
  // 0.12 V read as -0.038 deg, and with only two loads b followed (Lq 3.67 mH at zero current,
  // 4.61 mH at the limit, true 3.8 flat: +1.15 C on average); idling at 1.9 A or 3.5 A the same
  // machine's pairs put the angle at -0.017 and -0.008 deg (docs/estimator.md section 5.6). Such
  // a pair updates a and b with c considered, not estimated (a Schmidt update: c's uncertainty is
  // in s, its gain 0, its variance and mean kept).
  const bool teaches_c = !(std::abs(c.iq_mean_A) < bridge_band_A_);
  const std::array<double, kLqStates> k{ph[0] / s, ph[1] / s, teaches_c ? ph[2] / s : 0.0, ph[3] / s};
  const double innovation = lq - predicted;
  lq_H_ += k[0] * innovation;
  lq_b_H_ += k[1] * innovation;
  emf_d_Wb_ += k[2] * innovation;
  lq_b2_H_ += k[3] * innovation;
  // The covariance for any gain, P - K (P h)' - (P h) K' + K s K' (Joseph's form expanded); with
  // every gain the optimal one it is P - (P h)(P h)' / s.
  for (std::size_t i = 0; i < kLqStates; ++i) {
    for (std::size_t j = 0; j < kLqStates; ++j) {
      lq_p_[i][j] += -k[i] * ph[j] - ph[i] * k[j] + k[i] * k[j] * s;
    }
  }
  lq_resolved_ = saturation_variance_resolved();
  return true;
}

void InjectionScheduler::add_bend_prior(LqCovariance& p) const {
  // Until three loads have taught the curve it is a - b s: two anchors fix a - b s - b2 s^2 at
  // two points, and any split of the slope between b and b2 fits them (the prior's split moved
  // the incremental at one anchor by the other's distance). With a third, b2 enters with b's
  // prior, and with it every (a, b) that keeps the first two anchors' secants what they have
  // learned: a + b2 alpha, b + b2 beta with alpha - beta s - s^2 = 0 at both, alpha = -s1 s2,
  // beta = -(s1 + s2). The state's mean stays; its covariance takes v v' var(b2),
  // v = (alpha, beta, 0, 1).
  const double s1 = lq_anchors_[0];
  const double s2 = lq_anchors_[1];
  const double b2_std = config_.lq_saturation_std_fraction * config_.lq_H;
  const std::array<double, kLqStates> v{-s1 * s2, -(s1 + s2), 0.0, 1.0};
  for (std::size_t i = 0; i < kLqStates; ++i) {
    for (std::size_t j = 0; j < kLqStates; ++j) {
      p[i][j] += v[i] * v[j] * b2_std * b2_std;
    }
  }
}

bool InjectionScheduler::listens(const SchedulerInput& in) const {
  if (!config_.learn_lq || !config_.lq_listening || event_listened_ || config_.method != InjectionMethod::kFixedMagnitude ||
      lq_anchor_count_ >= kMaxLqAnchors || !std::isfinite(winding_rs_ohm_) ||
      !(std::abs(in.omega_e_rad_s) >= config_.min_speed_for_angle_rad_s)) {
    return false;
  }
  const double iq = in.motoring_ref_A.q;
  if (!(std::abs(lq_secant_H(iq) * in.omega_e_rad_s * iq) >= config_.lq_learning_min_voltage_V)) {
    return false;
  }
  // A fifth of a lever to spare: the pair's mean iq, by which learn_lq places it, may lie a
  // little nearer an anchor than the load it was started at (it would then be taken at the
  // anchor's s, teach no new one, and the next event would listen again).
  const double s_q = lq_shape_.at(iq).s;
  const double lever = lq_lever();
  for (int k = 0; k < lq_anchor_count_; ++k) {
    if (std::abs(s_q - lq_anchors_[static_cast<std::size_t>(k)]) < 1.2 * lever) {
      return false;
    }
  }
  return true;
}

double InjectionScheduler::speed_change_limit_rad_s(const PairConditions& c) const {
  const double omega = 0.5 * std::abs(c.omega_e_mean_1_rad_s + c.omega_e_mean_2_rad_s);
  return std::max(config_.max_speed_change_rad_s, config_.max_speed_change_fraction * omega);
}

void InjectionScheduler::retry_after_listening(double now_s) {
  // An event that ends with a listening pair and no accepted pair retries after the listening
  // pair, not after the refusal it followed.
  if (event_pairs_ == 0) {
    next_event_s_ = std::max(next_event_s_, now_s + config_.retry_s);
    retry_after_s_ = std::max(retry_after_s_, next_event_s_);
  }
}

void InjectionScheduler::finish_listening(const SchedulerInput& in) {
  ++listening_pairs_;
  ++learned_version_;  // (the drive publishes the counts with what was learned)
  if (level_index_ >= event_level_count()) {
    retry_after_listening(in.time_s);
  }
  // No speed-change guard: that guard keeps a pulse's pair from reading the motoring voltage's
  // change between its recordings as resistance. A listening pair separates nothing between its
  // recordings: it takes the means over both, <vd> against <w iq> sample by sample, and a speed
  // that moves between them moves both alike (a vehicle accelerating in torque mode refused
  // every one; docs/estimator.md section 5.1). The load change stays guarded: the pair places
  // its secant at one load.
  const PairConditions c = recorder_.conditions();
  const FitSums total = recorder_.sums().total();
  if (c.any_modulation_clipped || !(total.n > 0.0) ||
      !(unexplained_load_change_A(c, c.iq_mean_1_A - c.iq_mean_2_A) <= config_.max_load_change_A)) {
    return;
  }
  // No pulse, no resistance of its own: the filter's (learn_lq takes it when known, as listens()
  // asks), and as the noise of <vd> the spread of the two recordings' difference (where the speed
  // moved between them, that spread holds the curve's present error times the change too: a
  // wider variance, the safe side).
  FitResult fit;
  fit.rs_ohm = winding_rs_ohm_;
  fit.var_rs = winding_rs_var_ohm2_;
  fit.residual_rms_V = std::sqrt(total.yty / total.n);
  if (learn_lq(c, fit, in)) {
    ++listening_learned_;
  }
}

double InjectionScheduler::vx_variance_at(double bus_offset_V) const {
  // Vx at the reference bus plus the slope's error times the bus's distance from it (the
  // period's voltages were referred with the slope learned so far): h = (1, u).
  const double u = bus_offset_V;
  const double var = vx_var_ + 2.0 * u * vx_cov_ + u * u * vx_slope_var_;
  return std::isfinite(var) ? std::max(var, 0.0) : vx_var_;
}

void InjectionScheduler::learn_vx(double bus_offset_V, double vx_V, double var_V2) {
  // A Kalman update of (Vx, slope) with the Vx an event learned at its bus, referred with the
  // slope learned so far: vx_V = Vx + (slope - learned slope) u, h = (1, u). At one bus the
  // slope learns nothing; events at two buses tell the dead time's share from the drop's.
  const double u = bus_offset_V;
  learned_bus_offset_V_ = u;
  const double p0 = vx_var_ + u * vx_cov_;        // (P h)_0
  const double p1 = vx_cov_ + u * vx_slope_var_;  // (P h)_1
  const double s = p0 + u * p1 + var_V2;
  if (s > 0.0 && std::isfinite(s) && std::isfinite(vx_V)) {
    const double k0 = p0 / s;
    const double k1 = p1 / s;
    const double innovation = vx_V - vx_V_;
    vx_learned_ = true;
    vx_V_ += k0 * innovation;
    vx_slope_ += k1 * innovation;
    vx_var_ -= k0 * p0;
    vx_cov_ -= k0 * p1;
    vx_slope_var_ -= k1 * p1;
  }
  drift_vx();
}

void InjectionScheduler::drift_vx() {
  // The next event's prior: Vx may drift meanwhile (the bridge warms), by a share of the error
  // held and an absolute part. The share is of E[Vx^2] = Vx^2 + var(Vx): a guess of 0 that no
  // event has learned yet still drifts by the share of its uncertainty.
  const double share_sq = config_.vx_drift_fraction * config_.vx_drift_fraction;
  vx_var_ += config_.vx_drift_std_V * config_.vx_drift_std_V + share_sq * (vx_V_ * vx_V_ + vx_var_);
  ++learned_version_;
}

MeansFit InjectionScheduler::sample_fit_fixed_vx(double vx_V) const {
  // The event's sample fit (Eq. 22 for turning pulses) with Vx held at vx_V, its pairs' Lq
  // terms refitted with the curve learned by now, to first order in the sample fit
  // Rs = sum(dId y) / sum(dId^2) (the means' are refitted in step()).
  FitOptions options = fit_options(false);
  options.fixed_vx_V = config_.fit_dead_time ? vx_V : 0.0;
  const FitResult f = solve_fit(event_sums_, options);
  MeansFit out;
  out.valid = f.valid;
  out.rs_ohm = f.rs_ohm;
  out.var_rs = f.var_rs;
  out.drs_dvx = f.drs_dvx;
  double shift = 0.0;
  double sample_x_sq = 0.0;
  for (int j = 0; j < std::min(event_pairs_, InjectionConfig::kMaxLevels); ++j) {
    const LqTerm& t = event_pair_lq_[static_cast<std::size_t>(j)];
    const std::array<double, 3> change = lq_change_H(t);
    shift += t.secant_x_sum_A_V_H * change[0] + t.incremental_x_sum_A_V_H * change[1] + t.emf_x_sum_A_V_Wb * change[2];
    sample_x_sq += t.x_sq_sum_A2;
  }
  if (sample_x_sq > 0.0) {
    out.rs_ohm += shift / sample_x_sq;
  }
  return out;
}

bool InjectionScheduler::event_joint_fit() const {
  // A configuration that can learn Vx (InjectionConfig::can_learn_vx), in an event whose pairs
  // did reverse the current vector: light load, off the voltage limit, not too fast.
  const bool reversed = !event_field_weakening_ && event_max_iq_A_ <= config_.vx_learning_max_iq_fraction * event_min_f_A_ &&
                        event_max_speed_ <= config_.vx_learning_max_speed_rad_s;
  return config_.can_learn_vx() && reversed && event_pairs_ >= 2;
}

double InjectionScheduler::event_time_s() const {
  return event_start_s_ + event_pairs_mean(event_time_sum_s_, event_time_plain_sum_s_);
}

double InjectionScheduler::event_pairs_mean(double weighted_sum, double plain_sum) const {
  // Weighted by the pairs' information where any has a weight, else plain.
  return event_time_weight_ > 0.0 ? weighted_sum / event_time_weight_ : plain_sum / std::max(event_pairs_, 1);
}

double InjectionScheduler::rest_speed_rad_s() const {
  // A shaft below a tenth of the time-based floor rests: the retry after a lost speed waits for
  // it, and a joint fit at it takes the levels' geometry (finish_event).
  return 0.1 * config_.min_speed_for_angle_rad_s;
}

double InjectionScheduler::refusal_jitter() {
  // An event that yielded nothing (every pair refused, rejected or aborted) is followed by the
  // next one at the interval or after retry_s, as the refusal's path has it, and the first such
  // delay is kept exactly: a one-off refusal (a speed ramp, a load step) is over by then, and
  // the events keep their place in the duty. A second refusal in a row may be a periodic duty
  // whose period divides the delay (a press at 60 strokes a minute and events or retries 1 s
  // apart), met again at the phase that refused the event: from then on, until an event yields
  // pairs, each delay is scaled by 1 + retry_jitter v, v uniform in [0, 1), which moves that
  // phase over a whole period of any duty up to retry_jitter times the delay long and never
  // shortens the delay (retry_s is the least time a refused event's transient is given;
  // docs/estimator.md §2, "Repeated refusals are jittered"). splitmix64 (Steele, Lea & Flood
  // 2014): a few multiplies once per refusal, no allocation, and the same sequence on every run
  // (its seed is fixed, not the scenario's).
  if (!last_event_refused_) {
    last_event_refused_ = true;
    return 1.0;
  }
  retry_rng_ += 0x9E3779B97F4A7C15ULL;
  std::uint64_t z = retry_rng_;
  z = (z ^ (z >> 30U)) * 0xBF58476D1CE4E5B9ULL;
  z = (z ^ (z >> 27U)) * 0x94D049BB133111EBULL;
  z ^= z >> 31U;
  const double v = static_cast<double>(z >> 11U) * 0x1.0p-53;  // [0, 1)
  return 1.0 + config_.retry_jitter * v;
}

void InjectionScheduler::delay_next_event(double now_s, double jitter) {
  // The delay still to run, scaled; not rewritten at all where the factor is 1 (bit-exact).
  if (jitter != 1.0) {
    next_event_s_ = now_s + jitter * std::max(next_event_s_ - now_s, 0.0);
  }
}

bool InjectionScheduler::event_uses_means() const {
  return event_joint_fit() || config_.method == InjectionMethod::kFixedMagnitude;
}

EventEstimate InjectionScheduler::finish_event(const SchedulerInput& in) {
  in_event_ = false;
  EventEstimate e;
  e.time_s = in.time_s;
  e.lq_H = lq_H_;
  e.lq_std_H = std::sqrt(lq_p_[0][0]);
  if (event_pairs_ == 0) {
    e.outcome = EventOutcome::kNoAcceptedPairs;
    const double jitter = refusal_jitter();
    retry_after_s_ = std::max(retry_after_s_, in.time_s + jitter * config_.retry_s);
    delay_next_event(in.time_s, jitter);
    return e;
  }
  e.pairs = event_pairs_;
  last_event_refused_ = false;
  e.measured_at_s = event_time_s();
  e.measured_from_s = e.measured_at_s + event_pairs_mean(event_span_sums_s_[0], event_span_sums_s_[2]);
  e.measured_to_s = e.measured_at_s + event_pairs_mean(event_span_sums_s_[1], event_span_sums_s_[3]);
  double rs = 0.0;
  double var_rs = 0.0;
  // The event's bus, and the prior's variance of Vx there (vx_variance_at).
  const double bus_offset_V = event_bus_offset_V();
  const double vx_var_here = vx_variance_at(bus_offset_V);
  double vx = config_.fit_dead_time ? vx_V_ : 0.0;
  double var_vx = config_.fit_dead_time ? vx_var_here : 0.0;
  double cov_rs_vx = 0.0;     // Rs and Vx come out correlated (the magnet's error bar below)
  double drs_dvx_held = 0.0;  // Rs's dependence on a Vx held at the prior (shared by events)
  bool vx_held = false;
  double fw_bridge_ohm = 0.0; // the field-weakening bridge-pattern part of rs_systematic_std_ohm
  bool rs_from_means = true;  // the pairs' means (their Lq terms refitted in step()), or the sample fit
  // Rs from a fit with Vx held at a value whose variance is var: that variance adds through
  // drs/dVx, and Rs and Vx come out correlated by it.
  auto take_fixed_vx_fit = [&](const MeansFit& f, double var) {
    rs = f.rs_ohm;
    var_rs = f.var_rs + f.drs_dvx * f.drs_dvx * var;
    cov_rs_vx = f.drs_dvx * var;
  };

  // The event's own joint fit of Rs and Vx (several levels make it well conditioned) ...
  const int means = std::min(event_means_done_, std::min(event_pairs_, InjectionConfig::kMaxLevels));
  const MeansFit joint = event_joint_fit() ? solve_means_fit(event_means_.data(), means) : MeansFit{};
  // How well its levels separate Rs from Vx. With the rotor at rest (every pair's mean speed
  // below a tenth of min_speed_for_angle_rad_s, the rest the retry after a lost speed waits
  // for) the means' model is exact but for noise: no EMF, no harmonics, a sign pattern that
  // stays put. (Time-based pairs alone do not say it: below 30 electrical rad/s a rotor may
  // creep through a sector within a recording.)
  // The weights are then noise alone, and what a residual can do to Vx is the levels'
  // geometry (MeansFit::design_identifiability): weighted, a 24 V truck's standstill events at
  // F and 0.4 F, whose lower level is ten times noisier, read 0.02-0.04 against the geometry's
  // 0.155, and its stops never relearned a Vx they measured to 3 mV while the battery's
  // discharge moved it (docs/estimator.md section 4). Turning, a pair's residual carries what
  // the model lacks too (the zero crossings, the harmonics), and the weighted figure, which
  // discounts the pair that fits worse, is the guard: the geometry there let salient machines'
  // light-load events teach a biased Vx (the salient benchmark 1.89 -> 2.41 C RMS).
  const bool at_rest = event_max_speed_ < rest_speed_rad_s();
  e.joint_condition = at_rest ? joint.design_identifiability : joint.identifiability;
  e.vx_learning = joint.valid && e.joint_condition >= config_.vx_min_identifiability;
  // Nor from recordings that ran at different buses beyond what the learned bus slope can refer
  // between: each period's voltage is referred to the reference bus with the slope learned so
  // far, and where the slope's error times the spread of the recordings' buses exceeds the fit's
  // own error bar on Vx, the recordings disagree by that error and the fit takes it for Vx with a
  // bar that cannot show it. A 16 kHz slitter commissioned with its dead time 30 % short (the slope's
  // error 0.0048 V/V) learned Vx = 10.45 +- 0.018 V from an event spanning a step of its bus
  // from 540 to 655 V, and the filter followed the estimates 45 C low (docs/accuracy.md, "Unseen
  // motors, twelfth round"; docs/estimator.md section 4, "A bus that moves within an event"). Its
  // Rs takes Vx held at the prior, whose uncertainty at the event's bus the slope's includes. A
  // spread or a slope variance that is not a number refuses too.
  if (e.vx_learning) {
    double lo = event_pair_bus_V_[0][0];
    double hi = lo;
    for (int j = 0; j < means; ++j) {
      for (const double bus : event_pair_bus_V_[static_cast<std::size_t>(j)]) {
        lo = std::min(lo, bus);
        hi = std::max(hi, bus);
      }
    }
    e.bus_spread_V = hi - lo;
    const double misreference_V = std::sqrt(std::max(vx_slope_var_, 0.0)) * e.bus_spread_V;
    if (!std::isfinite(misreference_V) || misreference_V > std::sqrt(joint.var_vx)) {
      e.vx_learning = false;
      e.vx_refused_bus_spread = true;
    }
  }
  e.joint_rs_ohm = joint.rs_ohm;
  e.joint_vx_V = joint.vx_V;
  if (e.vx_learning && joint.var_vx > 0.0) {
    // ... fused with the prior on Vx: Gaussian conditioning of (Rs, Vx) on the combined Vx.
    const double vx_post = (joint.vx_V * vx_var_here + vx_V_ * joint.var_vx) / (vx_var_here + joint.var_vx);
    const double var_post = vx_var_here * joint.var_vx / (vx_var_here + joint.var_vx);
    // Fixed-magnitude pulses are flat, and so is any pulse at standstill: the means hold all of
    // the resistive signal (and none of the sample fit's closed-loop bias, section 5.2).
    const bool flat = config_.method == InjectionMethod::kFixedMagnitude ||
                      event_max_speed_ < config_.min_speed_for_angle_rad_s;
    if (flat) {
      const double gain = joint.cov_rs_vx / joint.var_vx;
      rs = joint.rs_ohm + gain * (vx_post - joint.vx_V);
      var_rs = joint.var_rs - gain * joint.cov_rs_vx + gain * gain * var_post;
      cov_rs_vx = gain * var_post;
    } else {
      // Fixed-angle and DC pulses turning in the rotor frame: the whole-turn means learn Vx,
      // but they cannot resolve the pulse's inductive voltage (below), so the Rs is the sample
      // fit's with Vx at the fused value. Conditioned on the means fit instead, a warm
      // restart's events at 60 rad/s read Rs to 2 mOhm with an error bar of 40 mOhm, and the
      // filter, starting from its guess, ignored them for seconds; at standstill the sample fit
      // read 1.4 % low where the means read right (docs/estimator.md section 5.2).
      const MeansFit f = sample_fit_fixed_vx(vx_post);
      if (!f.valid) {
        learn_vx(bus_offset_V, joint.vx_V, joint.var_vx);  // the means learned Vx all the same
        e.outcome = EventOutcome::kNoFit;
        return e;
      }
      take_fixed_vx_fit(f, var_post);
      rs_from_means = false;
    }
    vx = vx_post;
    var_vx = var_post;
    e.vx_from_event = true;
  } else {
    // One level, or a collinear event: Rs with Vx held at the prior, whose uncertainty adds.
    // Fixed-magnitude pulses are flat, so the pairs' means hold all of the resistive signal and
    // none of the closed-loop noise correlation (solve_means_fit_fixed_vx). Fixed-angle and DC
    // pulses turn in the rotor frame: their inductive voltage must be resolved sample by
    // sample (Eq. 22), which the means cannot do.
    MeansFit fixed;
    if (config_.method == InjectionMethod::kFixedMagnitude) {
      fixed = solve_means_fit_fixed_vx(event_means_.data(), means, vx);
    } else {
      fixed = sample_fit_fixed_vx(vx);
      rs_from_means = false;
    }
    if (!fixed.valid) {
      e.outcome = EventOutcome::kNoFit;
      return e;
    }
    take_fixed_vx_fit(fixed, var_vx);
    vx_held = true;
    drs_dvx_held = fixed.drs_dvx;
    if (config_.fit_dead_time && vx_slope_var_ > 0.0) {
      // Vx at the event's bus u is Vx at the reference plus the slope's error times u, and the
      // two errors are correlated (vx_variance_at): given the slope's error ds, Vx's error is
      // (u + cov / var_slope) ds plus an independent rest. The first part is the same for every
      // event until the slope is learned again, and it grows with the bus's distance from
      // where Vx is known (u + cov / var_slope; -cov / var_slope is that bus after an event
      // learned Vx there): a held Vx low by it reads Rs off by -drs/dVx of it (the fit's Rs
      // falls as the Vx it holds rises). The winding's filter learns ds (BusSlopeTerm).
      const double u_eff = bus_offset_V + vx_cov_ / vx_slope_var_;
      const double sensitivity = -fixed.drs_dvx * u_eff;
      const double slope_var_rs = std::min(sensitivity * sensitivity * vx_slope_var_, fixed.drs_dvx * fixed.drs_dvx * var_vx);
      if (std::isfinite(sensitivity) && std::isfinite(slope_var_rs)) {
        e.bus_slope_sensitivity_ohm = sensitivity;
        e.rs_bus_slope_var_ohm2 = slope_var_rs;
        e.bus_slope = vx_slope_;
        e.bus_slope_var = vx_slope_var_;
      }
    }
    if (event_field_weakening_ || config_.separation == Separation::kUnipolar) {
      // At the voltage limit the bridge's term is most of the pair's signal (the current
      // vector only turns) and the sign pattern is least exact (docs/estimator.md §2): its
      // model error, a fraction of Vx, adds to the estimate's variance, as a share of it that
      // consecutive estimates have in common. A unipolar pair is one-sided too (0, then -F):
      // the part of that error that is even in the pulse cancels only in a bipolar pair's
      // difference (Eqs. 39-44 against 33-38). On the 30 mOhm IPM at 314 rad/s its estimates
      // read 6 % low, 0.4 % of the bridge's term, where bipolar ones read right (docs/accuracy.md,
      // "The robustness suite under the other methods").
      const double bridge = config_.field_weakening_pattern_error * vx * fixed.drs_dvx;
      const double rest = event_field_weakening_ ? config_.field_weakening_rs_error * fixed.rs_ohm : 0.0;
      const double model_sq = bridge * bridge + rest * rest;
      var_rs += model_sq;
      e.rs_systematic_std_ohm = std::sqrt(model_sq);
      fw_bridge_ohm = bridge;
    }
  }
  if (rs_from_means) {
    // The learned Lq's uncertainty, shared by the event's pairs and by the estimates that
    // follow until pairs teach it better: it adds to the variance and to the shared part. The
    // pairs weigh as in the means fit (Rs = sum w x y / sum w x^2 with Vx held; the joint fit
    // runs at light load and low speed, where the term is small, and takes the same weights).
    // Not for the sample fit of fixed-angle and DC events: their vector turns through the
    // rotor frame, the term's first-order sensitivity is large and mixes with the fitted
    // inductive regressor, and on the DC baseline at speed (whose estimates are tens of per
    // cent off for other reasons) the wider error bar let more of them through the filter's
    // gate: its ±2σ coverage fell from 61 % to 16 %. Their Lq terms are refitted all the same.
    const int n = std::min(std::min(event_pairs_, InjectionConfig::kMaxLevels), means);
    double norm = 0.0;
    for (int j = 0; j < n; ++j) {
      const std::optional<PairMeans>& m = event_means_[static_cast<std::size_t>(j)];
      norm += m ? m->w * m->x_rs * m->x_rs : 0.0;
    }
    LqGradient g;
    for (int j = 0; norm > 0.0 && j < n; ++j) {
      const auto k = static_cast<std::size_t>(j);
      if (event_means_[k]) {  // a pair without means is not in the fit (FixedVxMeans skips it)
        const double c = event_means_[k]->w * event_means_[k]->x_rs / norm;
        g.add(c * event_pair_lq_[k].secant_mean_V_H, c * event_pair_lq_[k].incremental_mean_V_H,
              c * event_pair_lq_[k].emf_mean_V_Wb, event_pair_lq_[k].shape);
      }
    }
    const double lq_var = lq_variance(g);
    var_rs += lq_var;
    e.rs_systematic_std_ohm = std::sqrt(e.rs_systematic_std_ohm * e.rs_systematic_std_ohm + lq_var);
  }
  if (event_q_pairs_ == 0) {
    // Every pair time-based (the rotor at rest, or creeping through less than a turn per
    // recording): the current sensors' gain mismatch is not averaged over a turn. Measured
    // through the Park transform at the rest angle, a d current reads (1 + g_mean + (1/3)
    // sum_k g_k cos(2 theta_k)) of itself, theta_k the angle from phase k's axis; g_mean cancels
    // against the calibration (Eq. 1's ratio), the rest is this angle's, with the variance
    // sigma^2 / 6 for independent phase errors of sigma whatever the angle. A treadmill's shunts
    // (+3, -2.5, +1.5 %) read -2.1 to +0.3 % of Rs at five stop angles, where its turning pairs
    // read the same to 0.1 % and the same run without the gain errors +-0.1 % at all five
    // (docs/estimator.md section 5.7). Shared by every event at this stop: below.
    const double gain_ohm = rs * config_.current_gain_std_fraction / std::sqrt(6.0);
    var_rs += gain_ohm * gain_ohm;
  }
  // The largest error a bus that moved between a pair's recordings can make of its Rs at the bus
  // slope's uncertainty (bus_change_error_ohm): one slope error acts on every pair of the event
  // alike, so the largest bounds what their fit can take of it, and it is shared by the events
  // until the slope is learned.
  var_rs += event_bus_error_ohm_ * event_bus_error_ohm_;
  e.rs_systematic_std_ohm = std::hypot(e.rs_systematic_std_ohm, event_bus_error_ohm_);
  if (!plausible(rs, 0.0) || !(var_rs >= 0.0)) {
    e.outcome = EventOutcome::kImplausible;
    e.rs_ohm = rs;
    return e;
  }
  e.rs_ohm = rs;
  e.rs_std_ohm = std::sqrt(var_rs);
  if (config_.fit_dead_time) {
    if (e.vx_from_event) {
      learn_vx(bus_offset_V, joint.vx_V, joint.var_vx);
    } else {
      drift_vx();
    }
  }
  e.vx_V = vx;
  e.vx_std_V = std::sqrt(var_vx);

  // The EMF constant from the q axis of the angle-based pairs (Eqs. 34 / 40): averaged over
  // both recordings, <vq> - Rs <iq> - Vx <Gq> = Ld <w id> + Ke <wm>; differenced between them,
  // dvq - Rs diq - Vx dGq = Ld d(w id) + Ke dwm. The two solved together give Ke with the Ld
  // this pair measured, not the commissioned one: where <id> is far from zero (a unipolar pair,
  // <id> = -F/2; a field-weakening pair at the voltage limit, both levels negative) the
  // commissioned Ld's error would go into Ke (10 % of Ld is 14 C of magnet at rated speed). A
  // pair whose levels barely differ in w id (no Ld to measure) takes the commissioned Ld.
  double ke_sum = 0.0;
  double ke_sq_sum = 0.0;
  double dke_drs_sum = 0.0;  // the pairs' sensitivities to the event's Rs and Vx
  double dke_dvx_sum = 0.0;
  int ke_count = 0;
  for (int k = 0; k < event_q_pairs_; ++k) {
    const PairConditions& c = event_q_[static_cast<std::size_t>(k)];
    if (std::abs(c.omega_m_mean_rad_s) * config_.pole_pairs < config_.min_speed_for_angle_rad_s) {
      continue;
    }
    const double y = c.vq_mean_V - rs * c.iq_mean_A - vx * c.gq_mean;
    const double dy = c.dvq_V - rs * c.diq_A - vx * c.dgq;
    const double det = c.omega_e_id_mean_A_rad_s * c.domega_m_rad_s - c.omega_m_mean_rad_s * c.domega_e_id_A_rad_s;
    // Solvable where the recordings' d currents differ by 1 A or more (every injecting pair:
    // 2F bipolar, F unipolar, 0.7F field weakening); det is then about -<wm> d(w id).
    constexpr double kMinLevelDifference_A = 1.0;
    const bool ld_measured =
        std::abs(c.domega_e_id_A_rad_s) >= kMinLevelDifference_A * std::abs(c.omega_m_mean_rad_s) * config_.pole_pairs &&
        det != 0.0;
    const double ke = ld_measured ? (c.omega_e_id_mean_A_rad_s * dy - c.domega_e_id_A_rad_s * y) / det
                                  : (y - config_.ld_H * c.omega_e_id_mean_A_rad_s) / c.omega_m_mean_rad_s;
    ke_sum += ke;
    ke_sq_sum += ke * ke;
    // dKe/dRs and dKe/dVx of the expression above (y and dy are linear in both).
    dke_drs_sum += ld_measured ? (c.domega_e_id_A_rad_s * c.iq_mean_A - c.omega_e_id_mean_A_rad_s * c.diq_A) / det
                               : -c.iq_mean_A / c.omega_m_mean_rad_s;
    dke_dvx_sum += ld_measured ? (c.domega_e_id_A_rad_s * c.gq_mean - c.omega_e_id_mean_A_rad_s * c.dgq) / det
                               : -c.gq_mean / c.omega_m_mean_rad_s;
    ++ke_count;
  }
  if (ke_count > 0) {
    e.has_emf = true;
    const double n = ke_count;
    e.ke_V_s_per_rad = ke_sum / n;
    e.ke_pairs = ke_count;
    e.ke_pair_variance = ke_count > 1 ? std::max(0.0, (ke_sq_sum - n * e.ke_V_s_per_rad * e.ke_V_s_per_rad) / (n - 1.0)) : 0.0;
    // Ke's errors through the event's Rs and Vx (docs/estimator.md §8, the magnets' error
    // bar). A Vx error moves the fitted Rs with it (dRs/dVx = d), and in Ke the two largely
    // cancel: the bridge's q-axis term against the resistive one, (a d + b) together.
    const double a = dke_drs_sum / n;
    const double b = dke_dvx_sum / n;
    const double d = vx_held ? drs_dvx_held : (var_vx > 0.0 ? cov_rs_vx / var_vx : 0.0);
    const double rs_sys_sq = e.rs_systematic_std_ohm * e.rs_systematic_std_ohm;
    // What consecutive events share is not averaged by the magnet filter: a Vx held at the
    // prior (every event until the next one that learns it), the Rs model's errors (the learned
    // Lq, the field-weakening rest), and the bridge's sign pattern, the fraction
    // field_weakening_pattern_error of the bridge's whole term (at low speed under load tens of
    // degrees of magnet; for field-weakening events it replaces the Rs part of the same error).
    const double held_sq = vx_held ? (a * d + b) * (a * d + b) * var_vx : 0.0;
    const double pattern = config_.field_weakening_pattern_error * vx * (a * d + b);
    const double systematic = held_sq + pattern * pattern + a * a * std::max(0.0, rs_sys_sq - fw_bridge_ohm * fw_bridge_ohm);
    // The rest is the event's own: Rs's noise, and with a Vx the event fitted, the joint fit's
    // (Rs, Vx) with their covariance.
    const double own = vx_held ? a * a * std::max(0.0, var_rs - d * d * var_vx - rs_sys_sq)
                               : a * a * std::max(0.0, var_rs - rs_sys_sq) + 2.0 * a * b * cov_rs_vx + b * b * var_vx;
    e.ke_shared_std_V_s_per_rad = std::sqrt(std::max(own, 0.0));
    e.ke_systematic_std_V_s_per_rad = std::sqrt(systematic);
  }
  if (vx_held) {
    // A Vx held at the prior moves every event's Rs the same way until an event learns it
    // again: the winding's filter must not average it away (with the configured prior of 3 V, a
    // unipolar drive restarted without a stored Vx read 36 C high on average with the truth
    // inside its band 25 % of the time; docs/estimator.md section 4). (After the magnet's
    // figures, which count the held Vx through (a d + b) of their own.)
    e.rs_systematic_std_ohm = std::hypot(e.rs_systematic_std_ohm, drs_dvx_held * std::sqrt(var_vx));
  }
  if (event_q_pairs_ == 0) {
    // Every pair at standstill (time-based): the rotor rests at one angle, so every event there
    // sees the same bridge sign pattern and the same position's errors, and the next event
    // repeats this one's error rather than averaging it (a newcomer's servo, estimates every
    // 0.5 s through 6-minute stops: the stops' mean errors -1.06, +0.78, -1.31, +0.73, -1.35 mOhm
    // against a band fused down to a third of one estimate's, its coverage 97 -> 59 % over each
    // stop). The whole error bar is shared: the band keeps one estimate's width while the rotor
    // rests (the gain is unchanged), and running events' smaller shares take over once it turns.
    // (The current sensors' gains at this angle, added above, are such an error too.)
    e.rs_systematic_std_ohm = e.rs_std_ohm;
  }
  // An event can date its Rs after its own end: a pair's time weighs its recordings by their d
  // currents, (t1 Id1 - t2 Id2) / (Id1 - Id2), which for two levels of one sign (a
  // field-weakening pair; any pair on a motoring point in field weakening) lies beyond the
  // second recording, some 3 times the recordings' spacing beyond on a point in field weakening.
  // The pair measured that time's resistance (its fit extrapolates the warming between its
  // recordings). A fixed-magnitude event keeps that date: DriveController holds the estimate
  // until the filter's clock reaches it (their levels differ by F_min at least, so the date lies
  // within the current limit over F_min times the recordings' spacing). A DC event's rotor-frame
  // levels can nearly coincide, and the reference DC heat-up dated one event 46 s ahead: those
  // are fused as now.
  if (config_.method != InjectionMethod::kFixedMagnitude) {
    // (A turning pulse's recordings are not two levels in the rotor's frame: no line.)
    e.measured_at_s = std::min(e.measured_at_s, e.time_s);
    e.measured_from_s = e.measured_to_s = e.measured_at_s;
  }
  return e;
}

const SchedulerOutput& InjectionScheduler::step(const SchedulerInput& in, const PeriodSample* sample) {
  // The output lives in the scheduler and is cleared field by field: a fresh one each period
  // zero-filled its 400 bytes (the two optionals' storage).
  SchedulerOutput& out = out_;
  out.injection_A = {};
  out.active = false;
  out.completed.reset();
  out.estimate.reset();
  out.phase = phase_;
  if (config_.method == InjectionMethod::kNone) {
    phase_ = SchedulerPhase::kIdle;
    return out;
  }
  if (listening_ && (in.release_motoring || speed_lost(in))) {
    // A listening pair gives way as a pair does, and its event ends there, but with what it has:
    // the listening pair injected nothing, so the event's accepted pairs (a level before the one
    // its torque refused) stand. No level starts after it: the motoring point that needed the
    // voltage, or the shaft that lost its speed, would end that pair and the event with it.
    listening_ = false;
    phase_ = SchedulerPhase::kIdle;
    recording_ = 0;
    level_index_ = std::max(level_index_, event_level_count());
    retry_after_listening(in.time_s);
    if (!in.release_motoring) {  // the speed lost
      retry_at_rest_ = true;
      rest_since_s_ = -1.0;
    }
    out.phase = phase_;
    return out;
  }
  const bool busy = phase_ != SchedulerPhase::kIdle;
  if (!in.enabled) {
    // A rest counts only while the drive watches the shaft (a disable or a lost sample may
    // hide any motion); and a pair that lost its speed before is no reason to hurry after.
    retry_at_rest_ = false;
    rest_since_s_ = -1.0;
    abort(out, in, AbortCause::kDisabled);
    return out;
  }
  // No pair may keep the field weakening held where the motoring point needs it to move, and
  // an angle-based pair cannot survive the rotor stopping or reversing.
  if (busy && in.release_motoring) {
    abort(out, in, AbortCause::kMotoringNeedsVoltage);
    return out;
  }
  if (busy && speed_lost(in)) {
    abort(out, in, AbortCause::kSpeedLost);
    return out;
  }

  if (in_event_) {
    event_bus_sum_V_ += in.bus_offset_V;  // the event's mean bus (finish_event)
    ++event_bus_periods_;
    // And each recording's (EventEstimate::bus_spread_V): a fixed-angle pair at speed records
    // both pulses in kPulseWait, recording_ saying which.
    const bool pulse = phase_ == SchedulerPhase::kPulseWait && (recording_ == 1 || recording_ == 2);
    if (phase_ == SchedulerPhase::kRecord1 || phase_ == SchedulerPhase::kRecord2 || pulse) {
      const std::size_t k = pulse ? static_cast<std::size_t>(recording_ - 1) : phase_ == SchedulerPhase::kRecord1 ? 0 : 1;
      pair_bus_sum_V_[k] += in.bus_offset_V;
      ++pair_bus_periods_[k];
    }
  }
  const double elapsed = in.time_s - phase_start_s_;
  auto enter = [&](SchedulerPhase p) {
    phase_ = p;
    phase_start_s_ = in.time_s;
  };

  switch (phase_) {
    case SchedulerPhase::kIdle: {
      if (!in_event_) {
        // A request starts an event early, but not before the retry delay that follows an
        // event which yielded nothing (a calibration must not hammer a motor it cannot inject).
        const bool requested = in.request_now && in.time_s >= retry_after_s_;
        bool rested = false;
        if (retry_at_rest_) {
          // At rest, not passing through zero: a tenth of the angle-based speed (3 rad/s at the
          // defaults), which a ramp through zero crosses in milliseconds.
          // And the motoring current holding (within half the load-change guard's tolerance):
          // the speed loop still settling from the stop moved iq between a pair's recordings,
          // and the bridge's error with it (a hoist's pair 0.06 s after it stopped read +1.7 %).
          if (std::abs(in.omega_e_rad_s) >= rest_speed_rad_s()) {
            rest_since_s_ = -1.0;
          } else if (rest_since_s_ < 0.0 || std::abs(in.motoring_ref_A.q - rest_iq_A_) > 0.5 * config_.max_load_change_A) {
            rest_since_s_ = in.time_s;
            rest_iq_A_ = in.motoring_ref_A.q;
          }
          // Not a shaft the winding's derating stalled: its load wants all the current the
          // derated limit leaves (9/10 of it or more), and a pulse's loss heats a winding
          // already at its limit. (With min_speed_for_angle_rad_s = 0 every recording is
          // angle-based, which a shaft at rest cannot give: no rest counts.)
          rested = rest_since_s_ >= 0.0 && in.time_s - rest_since_s_ >= config_.record_time_s &&
                   std::hypot(in.motoring_ref_A.d, in.motoring_ref_A.q) < 0.9 * motoring_limit_A_;
        }
        if (held_ || (in.time_s < next_event_s_ && !requested && !rested)) {
          break;
        }
        retry_at_rest_ = false;
        in_event_ = true;
        level_index_ = 0;
        event_sums_ = {};
        event_pairs_ = 0;
        event_means_done_ = 0;
        event_min_f_A_ = 0.0;
        event_max_iq_A_ = 0.0;
        event_max_speed_ = 0.0;
        event_time_weight_ = 0.0;
        event_time_sum_s_ = 0.0;
        event_time_plain_sum_s_ = 0.0;
        event_span_sums_s_ = {};
        event_start_s_ = in.time_s;
        event_q_pairs_ = 0;
        event_field_weakening_ = false;
        event_listened_ = false;
        event_bus_sum_V_ = 0.0;
        event_bus_periods_ = 0;
        event_bus_error_ohm_ = 0.0;
        next_event_s_ = in.time_s + config_.interval_s;
      }
      if (level_index_ >= event_level_count()) {
        // The event's estimate needs each accepted pair's means, and each costs a regression
        // as large as a pair's own fit: one per control period, then the estimate, so that no
        // period carries more than one fit (the worst-case step, docs/performance.md).
        if (event_uses_means() && event_means_done_ < std::min(event_pairs_, InjectionConfig::kMaxLevels)) {
          const auto j = static_cast<std::size_t>(event_means_done_++);
          event_means_[j] = pair_means(event_pair_sums_[j], config_.fit_inductance);
          if (event_means_[j]) {
            // Each pair saw the winding's resistance of its own time: referred to the event's
            // time (its pairs' weighted mean time, EventEstimate::measured_at_s) by the change
            // the thermal model predicts, Rs(t_j) = Rs + rate (t_j - t_event). Otherwise the
            // joint fit reads a winding warming (or cooling) between its levels as inverter
            // voltage: under load the reference machine warms 0.4 % of Rs a second at 60 times
            // thermal speed, and the levels lie 0.1-0.3 s apart.
            event_means_[j]->y -= in.rs_rate_ohm_per_s * (event_pair_time_s_[j] - event_time_s()) * event_means_[j]->x_rs;
            // And its Lq term refitted with the curve learned since, the event's own pairs
            // included (a pair fitted with the commissioned Lq before any pair had taught the
            // curve would keep that error otherwise). The sample fit of fixed-angle and DC
            // events is refitted alike in finish_event.
            const std::array<double, 3> change = lq_change_H(event_pair_lq_[j]);
            event_means_[j]->y += event_pair_lq_[j].secant_mean_V_H * change[0] +
                                  event_pair_lq_[j].incremental_mean_V_H * change[1] +
                                  event_pair_lq_[j].emf_mean_V_Wb * change[2];
          }
          break;
        }
        out.estimate = finish_event(in);
        break;
      }
      if (in.motoring_settling) {
        break;  // the pair waits for the motoring point (SchedulerInput::motoring_settling)
      }
      double tw = config_.tw_s;
      if (config_.method == InjectionMethod::kFixedAngle &&
          std::abs(in.omega_e_rad_s) >= config_.min_speed_for_angle_rad_s) {
        tw = std::max(config_.tw_s, config_.window_arc_rad / std::abs(in.omega_e_rad_s));
      }
      const double wanted = config_.f_A * config_.levels[static_cast<std::size_t>(level_index_)];
      const Budget b = budget(in, tw, wanted);
      if (b.f_A < config_.f_min_A) {
        PairResult r;
        r.outcome = b.limiting;
        r.method = config_.method;
        r.separation = config_.separation;
        r.time_s = in.time_s;
        r.f_A = b.f_A;
        r.level_index = level_index_;
        out.completed = r;
        ++level_index_;
        if (event_pairs_ == 0 && level_index_ >= config_.level_count) {
          // Nothing at all this time: try again soon rather than a whole interval later.
          // (finish_event, next period, counts the refusal and jitters a repeated one)
          next_event_s_ = in.time_s + config_.retry_s;
          retry_after_s_ = next_event_s_;
        }
        if (b.limiting == PairOutcome::kSkippedTorqueDisturbance && listens(in)) {
          listening_ = true;
          event_listened_ = true;
          f_A_ = 0.0;
          field_weakening_ = false;
          fw_low_level_ = 0.0;
          begin_pair(in);
          phase_start_s_ = in.time_s;
        }
        break;
      }
      f_A_ = b.f_A;
      field_weakening_ = b.field_weakening;
      fw_low_level_ = b.field_weakening ? b.low_A / b.f_A : 0.0;
      begin_pair(in);
      phase_start_s_ = in.time_s;
      break;
    }

    case SchedulerPhase::kRampUp:
    case SchedulerPhase::kRampDown:
      if (elapsed >= config_.tw_s) {
        const double reached = level_to_;
        if (recording_ == 0 && ramp_count_ == 0) {
          // Up to the level of recording 1.
          ++ramp_count_;
          enter(SchedulerPhase::kSettle);
        } else if (recording_ == 1) {
          // Between the recordings: down to zero, then up to the level of recording 2.
          ++ramp_count_;
          const double second = level_for(2);
          // (kRecord1 ramped to zero already when the levels differ in sign.)
          if (reached != second) {
            level_from_ = reached;
            level_to_ = second;
            enter(SchedulerPhase::kRampUp);
          } else {
            enter(SchedulerPhase::kSettle);
          }
        } else {
          // After recording 2: the pair is done.
          enter(SchedulerPhase::kFinish);
        }
      }
      break;

    case SchedulerPhase::kSettle:
      if (elapsed >= config_.settle_s) {
        if (recording_ == 0) {
          recording_ = 1;
          enter(SchedulerPhase::kRecord1);
        } else {
          enter(time_based_ ? SchedulerPhase::kRecord2 : SchedulerPhase::kWaitArc);
          if (time_based_) {
            recorder_.begin_second(in.time_s + period_s_);
          }
        }
      }
      break;

    case SchedulerPhase::kRecord1:
      if (sample != nullptr) {
        recorder_.add_first(*sample);
        const double target = time_based_ ? config_.record_time_s : record_arc_rad_;
        if (recorder_.first_extent() >= target ||
            recorder_.first_size() >= recorder_capacity_) {
          if (!time_based_) {
            // Room for the transition: its ramps and settling at the present speed.
            // Levels of opposite sign pass through zero (two ramps), others take one.
            const double l1 = level_for(1);
            const double l2 = level_for(2);
            const int ramps = l1 == l2 ? 0 : (l1 * l2 < 0.0 ? 2 : 1);
            const double transition_s = ramps * config_.tw_s + config_.settle_s + 4.0 * period_s_;
            const double needed = recorder_.first_extent() + std::abs(in.omega_e_rad_s) * transition_s;
            origin2_ = recorder_.first_origin() + delta_theta(needed, in.omega_e_rad_s);
            recorder_.begin_second(origin2_);
          }
          const double first = level_for(1);
          const double second = level_for(2);
          if (first != second) {
            level_from_ = first;
            level_to_ = first * second < 0.0 ? 0.0 : second;
            enter(std::abs(level_to_) < std::abs(first) ? SchedulerPhase::kRampDown : SchedulerPhase::kRampUp);
          } else {
            enter(SchedulerPhase::kSettle);
          }
        }
      }
      break;

    case SchedulerPhase::kWaitArc:
      if (sample != nullptr && recorder_.coordinate(*sample) >= origin2_) {  // records() asks the same
        recording_ = 2;
        enter(SchedulerPhase::kRecord2);
        recorder_.add_second(*sample);
      }
      break;

    case SchedulerPhase::kRecord2:
      recording_ = 2;
      if (sample != nullptr) {
        recorder_.add_second(*sample);
        if (recorder_.second_complete(*sample)) {
          if (level_for(2) != 0.0) {
            level_from_ = level_for(2);
            level_to_ = 0.0;
            enter(SchedulerPhase::kRampDown);
          } else {
            enter(SchedulerPhase::kFinish);
          }
        }
      }
      break;

    case SchedulerPhase::kPulseWait: {
      // Fixed-angle: recording_ says which pulse; record across the pulse arc plus a tail for
      // the current to follow the envelope back to zero.
      const double tail = config_.settle_s * std::abs(in.omega_e_rad_s);
      if (sample != nullptr) {
        const double phi_sample = pulse_phase(sample->theta_e_rad);
        if (recording_ == 1) {
          if (phi_sample >= 0.0) {
            recorder_.add_first(*sample);
          }
          if (phi_sample >= pulse_arc_rad_ + tail) {
            const double needed = pulse_arc_rad_ + tail + 4.0 * std::abs(in.omega_e_rad_s) * period_s_;
            const double dtheta = delta_theta(needed, in.omega_e_rad_s);
            origin2_ = recorder_.first_origin() + dtheta;
            recorder_.begin_second(origin2_);
            pulse_start_theta_ += direction_ * dtheta;
            theta_f_unwrapped_ += direction_ * dtheta;
            recording_ = 2;
          }
        } else if (phi_sample >= 0.0) {
          recorder_.add_second(*sample);
          if (recorder_.second_complete(*sample)) {
            enter(SchedulerPhase::kFinish);
          }
        }
      }
      break;
    }

    case SchedulerPhase::kFinish:
      break;
  }

  if (phase_ == SchedulerPhase::kFinish) {
    if (listening_) {
      finish_listening(in);  // (its level was counted refused when it began)
      listening_ = false;
    } else {
      out.completed = finish_pair(in);
      ++level_index_;
    }
    phase_ = SchedulerPhase::kIdle;
    recording_ = 0;
  }

  out.phase = phase_;
  out.active = phase_ != SchedulerPhase::kIdle;
  out.injection_A = injection_current(in);
  if (out.active && !listening_) {
    // The budget sized the pulse at the pair's start; the motoring current moves on (the speed
    // loop's answer to a set-point or a load, up to the drive's limit), and the pulse on top of
    // it took a 48 V servo, a hoist and the 30 mOhm IPM past their current limits into the
    // over-current trip (docs/estimator.md section 2, "Guards"). The sum never leaves the
    // limit: a pulse the motoring current has crowded by a little (its ripple, on a pair sized
    // to the limit) is cut to fit, by at most kMaxCut of itself; beyond that the motor's need
    // comes first and the pair ends now.
    const Dq& m = in.motoring_ref_A;
    const Dq p = out.injection_A;
    const double limit = std::min(in.current_limit_A, config_.current_limit_A);  // as budget()'s
    const double total_sq = (m.d + p.d) * (m.d + p.d) + (m.q + p.q) * (m.q + p.q);
    if (!(total_sq <= limit * limit)) {
      // |m + s p| = limit for s in [0, 1]: a s^2 + 2 b s + c = 0.
      const double a = p.d * p.d + p.q * p.q;
      const double b = m.d * p.d + m.q * p.q;
      const double c = m.d * m.d + m.q * m.q - limit * limit;
      const double disc = b * b - a * c;
      const double s_fit = a > 0.0 && c < 0.0 && disc >= 0.0 ? (std::sqrt(disc) - b) / a : 0.0;
      if (s_fit >= 1.0 - kMaxCut) {
        out.injection_A = {s_fit * p.d, s_fit * p.q};
      } else {
        abort(out, in, AbortCause::kCurrentLimit);
      }
    }
  }
  return out;
}

}  // namespace pmsm::core
