// Plant emulator. The physics, its conventions and every modelling choice are written down
// in docs/plant.md; the comments here say why the code is shaped the way it is.
//
// Conventions: amplitude-invariant Park transform (Eq. 2), theta_e = p·theta_m is the angle
// of the rotor d-axis from the phase-a axis, currents are positive into the motor, and the
// pole voltage of a phase is measured from the negative DC rail.
#include "pmsm/plant/plant.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <optional>
#include <utility>

#include "pmsm/fixed_sincos.hpp"
#include "pmsm/fmod_two_pi.hpp"
#include "pmsm/plant/emf.hpp"
#include "pmsm/plant/rng.hpp"
#include "pmsm/plant/thermal.hpp"

namespace pmsm::plant {
namespace {

constexpr double kTwoPi = 2.0 * std::numbers::pi;
constexpr double kSqrt3Half = 0.86602540378443864676;  // sin(2π/3)
constexpr double kTwoThirds = 2.0 / 3.0;

// cos and sin of theta, theta - 2π/3 and theta + 2π/3 (the axes of phases a, b, c).
struct Trig3 {
  std::array<double, 3> c{};
  std::array<double, 3> s{};
};

Trig3 trig3(double theta_e_rad) {
  const math::SinCos r = math::fixed_sincos(theta_e_rad);  // libm's within an ulp, at half the cost
  const double c0 = r.c;
  const double s0 = r.s;
  Trig3 t;
  t.c = {c0, -0.5 * c0 + kSqrt3Half * s0, -0.5 * c0 - kSqrt3Half * s0};
  t.s = {s0, -0.5 * s0 - kSqrt3Half * c0, -0.5 * s0 + kSqrt3Half * c0};
  return t;
}

double sign_of(double v) { return (v > 0.0) ? 1.0 : ((v < 0.0) ? -1.0 : 0.0); }

// Flux-current curve of one axis, without the magnet: linear, or the saturating curve
// psi = L_sat·i + (L - L_sat)·i_knee·x/sqrt(1 + x²), x = i/i_knee. Its incremental
// inductance falls smoothly from L at zero current to L_sat far beyond the knee.
struct AxisFlux {
  double L_H = 0.0;
  double L_sat_H = 0.0;
  double knee_A = 1.0;
  bool saturating = false;

  void eval(double i_A, double& psi_Wb, double& L_inc_H) const {
    if (!saturating) {
      psi_Wb = L_H * i_A;
      L_inc_H = L_H;
      return;
    }
    const double x = i_A / knee_A;
    const double r = std::sqrt(1.0 + x * x);
    psi_Wb = L_sat_H * i_A + (L_H - L_sat_H) * knee_A * x / r;
    L_inc_H = L_sat_H + (L_H - L_sat_H) / (r * r * r);
  }
};

enum class Drive { pwm, off, dq };
enum class Mech { ideal_dyno, stuck, sliding };

struct State {
  double id_A = 0.0;
  double iq_A = 0.0;
  double theta_m_rad = 0.0;    // unwrapped, so that non-integer ripple orders stay smooth
  double omega_m_rad_s = 0.0;
  double dyno_int_rad = 0.0;   // integral of the speed error of the PI dynamometer

  bool operator==(const State&) const = default;

  State plus(const State& d, double h) const {
    return State{id_A + h * d.id_A, iq_A + h * d.iq_A, theta_m_rad + h * d.theta_m_rad,
                 omega_m_rad_s + h * d.omega_m_rad_s, dyno_int_rad + h * d.dyno_int_rad};
  }
};

// Integrated quantities: energies and the phase-voltage integral for the voltage sensors.
struct Meters {
  double input_J = 0.0;
  double copper_J = 0.0;
  double iron_J = 0.0;
  double friction_J = 0.0;
  double load_J = 0.0;
  double cable_J = 0.0;
  std::array<double, 3> v_int_V_s{};

  void add(const Meters& p, double h) {
    input_J += h * p.input_J;
    copper_J += h * p.copper_J;
    iron_J += h * p.iron_J;
    friction_J += h * p.friction_J;
    load_J += h * p.load_J;
    cable_J += h * p.cable_J;
    for (std::size_t i = 0; i < 3; ++i) {
      v_int_V_s[i] += h * p.v_int_V_s[i];
    }
  }
};

// Everything the derivative evaluation knows besides the rates, for sampling and decisions.
struct Aux {
  std::array<double, 3> i_abc_A{};
  std::array<double, 3> v_phase_V{};  // phase-to-neutral
  std::array<double, 3> e_abc_V{};
  double torque_em_Nm = 0.0;
  double torque_cog_Nm = 0.0;
  double torque_load_Nm = 0.0;
  double omega_m_rad_s = 0.0;
  double blocked_pole_V = 0.0;  // floating pole voltage of the one blocked phase (gates off)
  double dc_bus_V = 0.0;
};

// What the derivative evaluation computes from the time, the state and the mechanical
// mode alone: everything but the bridge's applied voltage and what follows from it.
struct Motion {
  Trig3 tr;
  std::array<double, 3> i_abc{};
  std::array<double, 3> e_abc{};
  double omega = 0.0;
  double we = 0.0;
  double e_d = 0.0;
  double e_q = 0.0;
  double Ld_inc = 0.0;
  double Lq_inc = 0.0;
  double a_d = 0.0;  // everything of Eq. 3 except the applied voltage and the L·di/dt term
  double a_q = 0.0;
  double vdc = 0.0;
  double torque_em = 0.0;
  double torque_cog = 0.0;
  double torque_load = 0.0;
  double d_theta = 0.0;  // the mechanical states' derivatives
  double d_omega = 0.0;
  double d_dyno_int = 0.0;
  double friction_W = 0.0;
  double iron_W = 0.0;
  double copper_W = 0.0;
  double cable_W = 0.0;
  double load_W = 0.0;
};

// Modes held constant over one RK4 step; switching happens only between steps.
struct Modes {
  Mech mech = Mech::sliding;
  double slide_sign = 0.0;
  // Gates off: +1 / -1 = the phase conducts through its lower / upper diode (current into /
  // out of the motor); 0 = blocked (no current).
  std::array<int, 3> conduct{};
};

// Values fixed for one period.
struct PeriodInput {
  Drive drive = Drive::off;
  std::array<double, 3> duty{};
  double vd_V = 0.0;
  double vq_V = 0.0;
};

std::array<double, 3> currents_abc(double id_A, double iq_A, const Trig3& t) {
  const double ia = id_A * t.c[0] - iq_A * t.s[0];
  const double ib = id_A * t.c[1] - iq_A * t.s[1];
  return {ia, ib, -ia - ib};
}

void park(const std::array<double, 3>& abc, const Trig3& t, double& d, double& q) {
  d = kTwoThirds * (abc[0] * t.c[0] + abc[1] * t.c[1] + abc[2] * t.c[2]);
  q = -kTwoThirds * (abc[0] * t.s[0] + abc[1] * t.s[1] + abc[2] * t.s[2]);
}

// Piecewise-linear interpolation in a time table (times ascending; a repeated time is a step);
// ends held. Returns the value and its slope.
std::pair<double, double> interpolate_points(const std::vector<TimePoint>& pts, double t) {
  if (t <= pts.front().time_s) {
    return {pts.front().value, 0.0};
  }
  if (t >= pts.back().time_s) {
    return {pts.back().value, 0.0};
  }
  const auto it = std::upper_bound(pts.begin(), pts.end(), t, [](double v, const TimePoint& q) {
    return v < q.time_s;
  });
  const TimePoint& b = *it;
  const TimePoint& a = *(it - 1);
  const double dt = b.time_s - a.time_s;
  if (dt <= 0.0) {
    return {b.value, 0.0};
  }
  const double slope = (b.value - a.value) / dt;
  return {a.value + slope * (t - a.time_s), slope};
}

const PlantConfig& validated(const PlantConfig& config) {
  validate_plant_config(config);
  return config;
}

// An ADC's code for v; a reading that is no number (a model that diverged: Plant::diverged)
// reads as code 0, never through a float-to-integer cast of NaN, which is undefined. rint is
// nearbyint in the rounding mode the plant never changes; without trap semantics (the release
// build) the compiler inlines it.
template <typename T>
T clamp_code(double v, double lo, double hi) {
  if (std::isnan(v)) {
    return T{0};
  }
  return static_cast<T>(std::clamp(std::rint(v), lo, hi));
}

}  // namespace

struct Plant::Impl {
  PlantConfig cfg;
  EmfModel emf;
  ThermalNetwork thermal;
  GaussianRng rng;

  // Constants derived from the configuration.
  double Ts_s = 0.0;
  std::uint16_t period_code = 0;  // SensorSample::pwm_period_code
  double h_nominal_s = 0.0;
  double p = 3.0;
  double psi_m0_Wb = 0.0;
  AxisFlux d_axis;
  AxisFlux q_axis;
  double dead_time_fraction = 0.0;  // Td·fs
  double drop_V = 0.0;
  double band_A = 1.0;
  double kp_dyno = 0.0;
  double ki_dyno = 0.0;
  double current_lsb_A = 0.0;
  double current_full_codes = 0.0;  // 2^(bits - 1): the signed ADC's positive full scale
  double voltage_full_codes = 0.0;
  double dc_max_code = 0.0;
  double voltage_lsb_V = 0.0;
  double dc_lsb_V = 0.0;
  double encoder_counts = 0.0;
  bool ideal_dyno = false;

  // Per-period parameters from the temperatures.
  double rs_ohm = 0.0;          // the circuit's: the winding's and the cable's
  double winding_rs_ohm = 0.0;  // the winding's alone (its copper loss)
  double psi_m_Wb = 0.0;
  double iron_scale = 1.0;
  double ambient_C = 25.0;
  // The bus before its ripple, held for a period (update_bus_level); whether it moves at all,
  // and the link's decay over a period, exp(-Ts / (R C)).
  double bus_level_V = 0.0;
  bool bus_moves = false;
  double bus_decay = 0.0;
  mutable double dc_bus_cache_t_s = std::numeric_limits<double>::quiet_NaN();
  mutable double dc_bus_cache_V = 0.0;
  // evaluate_at_start's last motion and what it was computed from; the parameters it also
  // depends on (resistance, flux, load) change only between periods, where the time moves on,
  // or by a run-time change, which clears it (invalidate_evaluations).
  mutable Motion start_motion;
  mutable bool start_motion_valid = false;
  mutable double start_motion_t_s = 0.0;
  mutable Mech start_motion_mech = Mech::sliding;
  mutable double start_motion_slide_sign = 0.0;
  mutable State start_motion_state;
  // find_kink's trig3 at the end of a step, for motion() at the start of the next (a pure
  // function of the angle, kept as the bus voltage is).
  mutable double kept_trig_theta_e = std::numeric_limits<double>::quiet_NaN();
  mutable Trig3 kept_trig;
  // What the sample's evaluation computed, for state() at the same instant: valid until the
  // next period or a run-time change (set_*); keyed by the gates' state it was made with.
  Aux sample_aux;
  bool sample_aux_valid = false;
  bool sample_aux_gates = false;

  // State.
  State x;
  Meters meters;
  Modes modes;
  bool conduction_valid = false;
  std::uint64_t k = 0;  // index of the current sample
  hal::InverterCommand latched{};
  bool tripped = false;
  std::uint64_t trip_sample = 0;  // sample at which the over-current trip latched
  bool gates_now = false;  // gates switch in the period that starts at the current sample
  std::uint64_t sequence_errors = 0;
  // The time of the first period whose state came out no number (NaN or infinite), -1 while
  // finite: a model the integration could not follow (Plant::diverged).
  double diverged_at_s = -1.0;

  void check_finite() {
    if (diverged_at_s < 0.0 &&
        !std::isfinite(x.id_A + x.iq_A + x.theta_m_rad + x.omega_m_rad_s + x.dyno_int_rad)) {
      diverged_at_s = static_cast<double>(k - 1) * Ts_s;  // called after the period, k advanced
    }
  }
  hal::SensorSample sample{};
  std::array<double, 3> v_avg_V{};
  double copper_loss_W = 0.0;
  double iron_loss_W = 0.0;
  double friction_loss_W = 0.0;
  bool shaft_stuck = false;

  explicit Impl(const PlantConfig& config)
      : cfg(validated(config)),
        emf(config.emf),
        thermal(config.thermal,
                config.thermal.acceleration / config.inverter.pwm_frequency_Hz),
        rng(config.simulation.seed) {
    Ts_s = 1.0 / cfg.inverter.pwm_frequency_Hz;
    period_code = hal::pwm_period_code(cfg.inverter.pwm_frequency_Hz);
    h_nominal_s = Ts_s / static_cast<double>(cfg.simulation.substeps);
    p = static_cast<double>(cfg.motor.pole_pairs);
    psi_m0_Wb = psi_m_from_Ke(cfg.motor.ke_V_s_per_rad, cfg.motor.pole_pairs);
    d_axis = AxisFlux{cfg.motor.ld_H, cfg.saturation.ld_sat_H, cfg.saturation.id_knee_A,
                      cfg.saturation.enabled};
    q_axis = AxisFlux{cfg.motor.lq_H, cfg.saturation.lq_sat_H, cfg.saturation.iq_knee_A,
                      cfg.saturation.enabled};
    dead_time_fraction = cfg.inverter.dead_time_enabled
                             ? cfg.inverter.dead_time_s * cfg.inverter.pwm_frequency_Hz
                             : 0.0;
    drop_V = cfg.inverter.device_drop_enabled ? cfg.inverter.device_drop_V : 0.0;
    band_A = cfg.inverter.zero_current_band_A;
    configure_dyno();
    current_full_codes = std::ldexp(1.0, cfg.current_adc.bits - 1);
    current_lsb_A = cfg.current_adc.range_A / current_full_codes;
    voltage_full_codes = std::ldexp(1.0, cfg.phase_voltage_sensing.bits - 1);
    dc_max_code = std::ldexp(1.0, cfg.dc_bus_adc.bits) - 1.0;
    voltage_lsb_V =
        cfg.phase_voltage_sensing.range_V / std::ldexp(1.0, cfg.phase_voltage_sensing.bits - 1);
    dc_lsb_V = cfg.dc_bus_adc.full_scale_V / std::ldexp(1.0, cfg.dc_bus_adc.bits);
    encoder_counts = std::ldexp(1.0, cfg.encoder.bits);
    ambient_C = cfg.thermal.ambient_C;
    update_temperature_parameters();
    bus_level_V = source_V(0.0);
    bus_moves = !cfg.inverter.dc_source_points.empty() || cfg.inverter.dc_source_resistance_ohm > 0.0;
    if (cfg.inverter.dc_source_resistance_ohm > 0.0) {
      bus_decay = std::exp(-Ts_s / (cfg.inverter.dc_source_resistance_ohm * cfg.inverter.dc_link_capacitance_F));
    }

    x.theta_m_rad = cfg.mechanics.initial_angle_rad;
    x.omega_m_rad_s = ideal_dyno ? speed_reference(0.0).first : cfg.mechanics.initial_speed_rad_s;
    // The controller has sent nothing yet: gates off until the first command is latched.
    latched = hal::InverterCommand{};
    gates_now = false;
    finish_sample(false);
    set_flags();
  }

  // After a run-time change: the evaluations kept at the sample instant are no longer the model's.
  void invalidate_evaluations() {
    sample_aux_valid = false;
    start_motion_valid = false;
  }

  void configure_dyno() {
    ideal_dyno = cfg.load.profile == LoadProfile::speed_cycle && cfg.load.dyno_bandwidth_Hz <= 0.0;
    // PI speed loop of the dynamometer on the shaft inertia: critically damped, natural
    // frequency 2π·bandwidth, so J·s² + Kp·s + Ki has a double root at -ωn.
    const double wn = kTwoPi * cfg.load.dyno_bandwidth_Hz;
    kp_dyno = 2.0 * wn * cfg.mechanics.inertia_kg_m2;
    ki_dyno = wn * wn * cfg.mechanics.inertia_kg_m2;
  }

  // The supply's voltage at t (DESIGN §5's bus when no table is given).
  [[nodiscard]] double source_V(double t) const {
    return cfg.inverter.dc_source_points.empty() ? cfg.inverter.dc_bus_V
                                                 : interpolate_points(cfg.inverter.dc_source_points, t).first;
  }

  // The bus for the period that starts at t, from the power the motor drew in the one before
  // (the terminals' mean power; the bridge's conduction loss is left out): the link's capacitor
  // charged through the source's resistance by a constant current over the period, solved
  // exactly, so any time constant R·C is stable. Where the bus moves, the values kept at the
  // period's end were computed with the old level.
  void update_bus_level(double t, double power_W) {
    const double source = source_V(t);
    double level = source;
    if (cfg.inverter.dc_source_resistance_ohm > 0.0) {
      const double settled = source - cfg.inverter.dc_source_resistance_ohm * power_W / bus_level_V;
      level = settled + (bus_level_V - settled) * bus_decay;
    }
    constexpr double kMinBus_V = 1.0;  // a collapsed bus (the drive trips on its under-voltage long before)
    level = std::max(level, kMinBus_V);
    if (level != bus_level_V) {
      bus_level_V = level;
      dc_bus_cache_t_s = std::numeric_limits<double>::quiet_NaN();
      invalidate_evaluations();
    }
  }

  void update_temperature_parameters() {
    const auto& t = thermal.temperatures_C();
    winding_rs_ohm = cfg.motor.rs_at_C(t[ThermalNetwork::kWinding]);  // Eq. 1
    rs_ohm = winding_rs_ohm + cfg.motor.cable_at_C(ambient_C);
    psi_m_Wb = psi_m0_Wb * (1.0 + cfg.motor.magnet_temp_coefficient_per_C *
                                      (t[ThermalNetwork::kRotor] - cfg.motor.magnet_ref_temp_C));
    const double ratio = psi_m_Wb / psi_m0_Wb;
    iron_scale = cfg.iron_loss.enabled ? ratio * ratio : 0.0;
  }

  [[nodiscard]] double dc_bus_V(double t) const {
    if (!cfg.inverter.dc_ripple_enabled) {
      return bus_level_V;
    }
    // An RK4 step evaluates its middle twice and its end where the next step starts: the
    // last value is kept (a pure function of t within a period; cleared where the level moves).
    if (t != dc_bus_cache_t_s) {
      dc_bus_cache_t_s = t;
      dc_bus_cache_V = bus_level_V *
                       (1.0 + cfg.inverter.dc_ripple_fraction *
                                  math::fixed_sin(kTwoPi * cfg.inverter.dc_ripple_frequency_Hz * t));
    }
    return dc_bus_cache_V;
  }

  // Piecewise-linear interpolation in the load table; ends held. Returns value and slope.
  [[nodiscard]] std::pair<double, double> interpolate(double t) const { return interpolate_points(cfg.load.points, t); }

  // Imposed speed and its derivative.
  [[nodiscard]] std::pair<double, double> speed_reference(double t) const {
    if (cfg.load.points.empty()) {
      return {cfg.load.speed_rad_s, 0.0};
    }
    return interpolate(t);
  }

  // Load torque before ripple, for the torque profiles.
  [[nodiscard]] double load_torque_base(double t, double omega) const {
    switch (cfg.load.profile) {
      case LoadProfile::constant_torque:
        return cfg.load.torque_Nm;
      case LoadProfile::torque_steps: {
        double v = cfg.load.torque_Nm;
        for (const TimePoint& q : cfg.load.points) {
          if (q.time_s > t) {
            break;
          }
          v = q.value;
        }
        return v;
      }
      case LoadProfile::fan:
        return cfg.load.torque_Nm + cfg.load.fan_k_Nm_s2 * omega * std::abs(omega);
      case LoadProfile::torque_cycle:
        return interpolate(t).first;
      case LoadProfile::speed_cycle:
        break;
    }
    return 0.0;
  }

  void motion(double t, const State& s, const Modes& m, Motion& mo) const {
    const double theta_e = p * s.theta_m_rad;
    const Trig3& tr = mo.tr = (theta_e == kept_trig_theta_e) ? kept_trig : trig3(theta_e);
    double omega = s.omega_m_rad_s;
    double alpha_ref = 0.0;
    if (m.mech == Mech::ideal_dyno) {
      const auto [w, a] = speed_reference(t);
      omega = w;
      alpha_ref = a;
    } else if (m.mech == Mech::stuck) {
      omega = 0.0;
    }
    mo.omega = omega;
    const double we = mo.we = p * omega;
    mo.i_abc = currents_abc(s.id_A, s.iq_A, tr);

    // EMF in the rotor frame (Eq. 3 plus the harmonic terms kd, kq of Eqs. 33-36).
    double g_d = 0.0;
    double g_q = 1.0;
    emf.dq_shape(tr.c[0], tr.s[0], g_d, g_q);
    const double e_d = mo.e_d = we * psi_m_Wb * g_d;
    const double e_q = mo.e_q = we * psi_m_Wb * g_q;
    double psi_d_i = 0.0;
    double psi_q = 0.0;
    d_axis.eval(s.id_A, psi_d_i, mo.Ld_inc);
    q_axis.eval(s.iq_A, psi_q, mo.Lq_inc);
    mo.a_d = rs_ohm * s.id_A - we * psi_q + e_d;
    mo.a_q = rs_ohm * s.iq_A + we * psi_d_i + e_q;
    mo.vdc = dc_bus_V(t);
    for (std::size_t ph = 0; ph < 3; ++ph) {
      mo.e_abc[ph] = e_d * tr.c[ph] - e_q * tr.s[ph];
    }

    // Air-gap torque, consistent with the power converted by the EMF and by saliency.
    const double torque_em = mo.torque_em =
        1.5 * p * (psi_m_Wb * (g_d * s.id_A + g_q * s.iq_A) + psi_d_i * s.iq_A - psi_q * s.id_A);
    const double torque_cog = mo.torque_cog =
        cfg.cogging.enabled
            ? cfg.cogging.amplitude_Nm *
                  math::fixed_sin(cfg.cogging.order * s.theta_m_rad + cfg.cogging.phase_rad)
            : 0.0;

    // Iron loss P = k_h·|ω_e| + k_e·ω_e², applied as a drag torque with a Coulomb part
    // (hysteresis) and a viscous part (eddy currents) so that it is paid for mechanically.
    const double fe_coulomb_Nm = iron_scale * cfg.iron_loss.hysteresis_W_s_rad * p;
    const double fe_viscous_Nm_s = iron_scale * cfg.iron_loss.eddy_W_s2_rad2 * p * p;
    const double coulomb_Nm = cfg.mechanics.coulomb_Nm;
    const double viscous_Nm_s = cfg.mechanics.viscous_Nm_s_rad;
    const double ripple = (cfg.load.ripple_enabled && m.mech != Mech::ideal_dyno)
                              ? 1.0 + cfg.load.ripple_fraction *
                                          math::fixed_sin(cfg.load.ripple_order * s.theta_m_rad +
                                                          cfg.load.ripple_phase_rad)
                              : 1.0;

    double torque_load = 0.0;
    mo.d_dyno_int = 0.0;
    if (m.mech == Mech::ideal_dyno) {
      // The dynamometer takes whatever torque keeps the speed on its profile.
      const double sgn = sign_of(omega);
      const double friction = sgn * (coulomb_Nm + fe_coulomb_Nm) + (viscous_Nm_s + fe_viscous_Nm_s) * omega;
      torque_load = torque_em + torque_cog - friction - cfg.mechanics.inertia_kg_m2 * alpha_ref;
      mo.d_theta = omega;
      mo.d_omega = alpha_ref;
      mo.friction_W = coulomb_Nm * std::abs(omega) + viscous_Nm_s * omega * omega;
      mo.iron_W = fe_coulomb_Nm * std::abs(omega) + fe_viscous_Nm_s * omega * omega;
    } else {
      if (cfg.load.profile == LoadProfile::speed_cycle) {
        const auto [w_ref, a_ref] = speed_reference(t);
        torque_load = (kp_dyno * (omega - w_ref) + ki_dyno * s.dyno_int_rad +
                       cfg.mechanics.inertia_kg_m2 * a_ref) * ripple;
        mo.d_dyno_int = omega - w_ref;
      } else {
        torque_load = load_torque_base(t, omega) * ripple;
      }
      if (m.mech == Mech::stuck) {
        mo.d_theta = 0.0;
        mo.d_omega = 0.0;
        mo.friction_W = 0.0;
        mo.iron_W = 0.0;
      } else {
        const double sgn = m.slide_sign;
        const double drive = torque_em + torque_cog - torque_load;
        mo.d_theta = omega;
        mo.d_omega = (drive - sgn * (coulomb_Nm + fe_coulomb_Nm) -
                      (viscous_Nm_s + fe_viscous_Nm_s) * omega) / cfg.mechanics.inertia_kg_m2;
        mo.friction_W = sgn * coulomb_Nm * omega + viscous_Nm_s * omega * omega;
        mo.iron_W = sgn * fe_coulomb_Nm * omega + fe_viscous_Nm_s * omega * omega;
      }
    }
    mo.torque_load = torque_load;
    mo.copper_W = 1.5 * winding_rs_ohm * (s.id_A * s.id_A + s.iq_A * s.iq_A);
    mo.cable_W = 1.5 * (rs_ohm - winding_rs_ohm) * (s.id_A * s.id_A + s.iq_A * s.iq_A);
    mo.load_W = torque_load * omega;
  }

  // The derivative of the state and the powers at (t, s) for the given period input and
  // modes, from what motion() computed there. With motion(), the whole continuous-time model.
  void evaluate(const Motion& mo, const State& s, const PeriodInput& in, const Modes& m, State& ds,
                Meters& pw, Aux& aux) const {
    const Trig3& tr = mo.tr;
    const double we = mo.we;
    const double a_d = mo.a_d;
    const double a_q = mo.a_q;
    const double Ld_inc = mo.Ld_inc;
    const double Lq_inc = mo.Lq_inc;
    const std::array<double, 3>& i_abc = mo.i_abc;

    // Applied voltages.
    const double vdc = mo.vdc;
    aux.dc_bus_V = vdc;
    std::array<double, 3> pole{};
    double vd = 0.0;
    double vq = 0.0;
    bool zero_current = false;
    switch (in.drive) {
      case Drive::pwm: {
        for (std::size_t ph = 0; ph < 3; ++ph) {
          // Dead time and device drop oppose the current; inside the ripple band the PWM
          // ripple makes the current change sign within the period, so the average error
          // falls linearly to zero with the mean current.
          const double sgn = std::clamp(i_abc[ph] / band_A, -1.0, 1.0);
          const double duty = std::clamp(in.duty[ph] - dead_time_fraction * sgn, 0.0, 1.0);
          pole[ph] = duty * vdc - drop_V * sgn;
        }
        park(pole, tr, vd, vq);
        break;
      }
      case Drive::dq: {
        vd = in.vd_V;
        vq = in.vq_V;
        for (std::size_t ph = 0; ph < 3; ++ph) {
          pole[ph] = vd * tr.c[ph] - vq * tr.s[ph];
        }
        break;
      }
      case Drive::off: {
        int blocked = 0;
        std::size_t z = 0;
        for (std::size_t ph = 0; ph < 3; ++ph) {
          if (m.conduct[ph] > 0) {
            pole[ph] = -drop_V;  // lower diode
          } else if (m.conduct[ph] < 0) {
            pole[ph] = vdc + drop_V;  // upper diode
          } else {
            pole[ph] = 0.0;
            ++blocked;
            z = ph;
          }
        }
        if (blocked == 1) {
          // The blocked phase floats: choose its pole voltage so that its current stays
          // zero (d i_z / dt = 0); the linear equation follows from Eq. 3.
          double vd0 = 0.0;
          double vq0 = 0.0;
          park(pole, tr, vd0, vq0);
          const double cz = tr.c[z];
          const double sz = tr.s[z];
          const double num = cz * (vd0 - a_d) / Ld_inc - sz * (vq0 - a_q) / Lq_inc -
                             we * (s.id_A * sz + s.iq_A * cz);
          const double den = kTwoThirds * (cz * cz / Ld_inc + sz * sz / Lq_inc);
          pole[z] = -num / den;
          aux.blocked_pole_V = pole[z];
          park(pole, tr, vd, vq);
        } else if (blocked >= 2) {
          // All currents are zero: the terminals show the EMF, nothing else moves.
          zero_current = true;
          vd = a_d;
          vq = a_q;
          for (std::size_t ph = 0; ph < 3; ++ph) {
            pole[ph] = mo.e_d * tr.c[ph] - mo.e_q * tr.s[ph];
          }
        } else {
          park(pole, tr, vd, vq);
        }
        break;
      }
    }
    const double pole_mean = (pole[0] + pole[1] + pole[2]) / 3.0;
    for (std::size_t ph = 0; ph < 3; ++ph) {
      aux.v_phase_V[ph] = pole[ph] - pole_mean;
    }
    aux.e_abc_V = mo.e_abc;

    ds.id_A = zero_current ? 0.0 : (vd - a_d) / Ld_inc;
    ds.iq_A = zero_current ? 0.0 : (vq - a_q) / Lq_inc;
    ds.theta_m_rad = mo.d_theta;
    ds.omega_m_rad_s = mo.d_omega;
    ds.dyno_int_rad = mo.d_dyno_int;

    pw.friction_J = mo.friction_W;
    pw.iron_J = mo.iron_W;
    pw.input_J = aux.v_phase_V[0] * i_abc[0] + aux.v_phase_V[1] * i_abc[1] +
                 aux.v_phase_V[2] * i_abc[2];
    pw.copper_J = mo.copper_W;
    pw.cable_J = mo.cable_W;
    pw.load_J = mo.load_W;
    pw.v_int_V_s = aux.v_phase_V;

    aux.i_abc_A = i_abc;
    aux.torque_em_Nm = mo.torque_em;
    aux.torque_cog_Nm = mo.torque_cog;
    aux.torque_load_Nm = mo.torque_load;
    aux.omega_m_rad_s = mo.omega;
  }

  void evaluate(double t, const State& s, const PeriodInput& in, const Modes& m, State& ds,
                Meters& pw, Aux& aux) const {
    Motion mo;
    motion(t, s, m, mo);
    evaluate(mo, s, in, m, ds, pw, aux);
  }

  // The same where a step starts. The sample's evaluation at t_k and the period's first step
  // from there, and a step's redo up to an event, evaluate the same state at the same time in
  // the same mechanical mode: the last such motion is kept (a pure function of them, as the
  // bus voltage's cache is), which saves one evaluation in five.
  void evaluate_at_start(double t, const State& s, const PeriodInput& in, const Modes& m,
                         State& ds, Meters& pw, Aux& aux) const {
    if (!(start_motion_valid && t == start_motion_t_s && m.mech == start_motion_mech &&
          m.slide_sign == start_motion_slide_sign && s == start_motion_state)) {
      motion(t, s, m, start_motion);
      start_motion_valid = true;
      start_motion_t_s = t;
      start_motion_mech = m.mech;
      start_motion_slide_sign = m.slide_sign;
      start_motion_state = s;
    }
    evaluate(start_motion, s, in, m, ds, pw, aux);
  }

  // One classic RK4 step; the meters get the same weights, as extra states would.
  void rk4(double t, const State& s0, double h, const PeriodInput& in, const Modes& m,
           State& s1, Meters& dm, std::array<double, 3>* i0_abc_A = nullptr) const {
    State k1;
    State k2;
    State k3;
    State k4;
    Meters p1;
    Meters p2;
    Meters p3;
    Meters p4;
    Aux aux;
    evaluate_at_start(t, s0, in, m, k1, p1, aux);
    if (i0_abc_A != nullptr) {
      *i0_abc_A = aux.i_abc_A;
    }
    evaluate(t + 0.5 * h, s0.plus(k1, 0.5 * h), in, m, k2, p2, aux);
    evaluate(t + 0.5 * h, s0.plus(k2, 0.5 * h), in, m, k3, p3, aux);
    evaluate(t + h, s0.plus(k3, h), in, m, k4, p4, aux);
    const double w = h / 6.0;
    s1 = s0.plus(k1, w).plus(k2, 2.0 * w).plus(k3, 2.0 * w).plus(k4, w);
    dm = Meters{};
    dm.add(p1, w);
    dm.add(p2, 2.0 * w);
    dm.add(p3, 2.0 * w);
    dm.add(p4, w);
  }

  // Gates off: starts conduction from the present currents (after switching off).
  void init_conduction() {
    const Trig3 tr = trig3(p * x.theta_m_rad);
    const auto i_abc = currents_abc(x.id_A, x.iq_A, tr);
    constexpr double kZero_A = 1e-9;
    for (std::size_t ph = 0; ph < 3; ++ph) {
      modes.conduct[ph] = (std::abs(i_abc[ph]) > kZero_A) ? (i_abc[ph] > 0.0 ? 1 : -1) : 0;
    }
    enforce_blocked();
    conduction_valid = true;
  }

  // Makes the state satisfy the blocked-phase constraints exactly.
  void enforce_blocked() {
    int blocked = 0;
    std::size_t z = 0;
    for (std::size_t ph = 0; ph < 3; ++ph) {
      if (modes.conduct[ph] == 0) {
        ++blocked;
        z = ph;
      }
    }
    if (blocked >= 2) {
      modes.conduct = {0, 0, 0};
      x.id_A = 0.0;
      x.iq_A = 0.0;
    } else if (blocked == 1) {
      const Trig3 tr = trig3(p * x.theta_m_rad);
      auto i_abc = currents_abc(x.id_A, x.iq_A, tr);
      const std::size_t a = (z + 1) % 3;
      const std::size_t b = (z + 2) % 3;
      const double i_pair = 0.5 * (i_abc[a] - i_abc[b]);
      i_abc[a] = i_pair;
      i_abc[b] = -i_pair;
      i_abc[z] = 0.0;
      park(i_abc, tr, x.id_A, x.iq_A);
    }
  }

  // Decides the modes for the RK4 step starting at (t, x).
  void decide_modes(double t, const PeriodInput& in) {
    // Mechanics first: the conduction decisions below need the right speed for the EMF.
    if (ideal_dyno) {
      modes.mech = Mech::ideal_dyno;
    } else if (x.omega_m_rad_s != 0.0) {
      modes.mech = Mech::sliding;
      modes.slide_sign = sign_of(x.omega_m_rad_s);
    } else {
      // At standstill the shaft stays stuck while static friction can hold it.
      Modes probe = modes;
      probe.mech = Mech::stuck;
      State ds;
      Meters pw;
      Aux aux;
      evaluate(t, x, in, probe, ds, pw, aux);
      const double drive = aux.torque_em_Nm + aux.torque_cog_Nm - aux.torque_load_Nm;
      const double hold = std::max(cfg.mechanics.breakaway_Nm,
                                   cfg.mechanics.coulomb_Nm +
                                       iron_scale * cfg.iron_loss.hysteresis_W_s_rad * p);
      if (std::abs(drive) <= hold) {
        modes.mech = Mech::stuck;
        modes.slide_sign = 0.0;
      } else {
        modes.mech = Mech::sliding;
        modes.slide_sign = sign_of(drive);
      }
    }
    shaft_stuck = modes.mech == Mech::stuck;
    if (in.drive != Drive::off) {
      return;
    }
    int blocked = 0;
    std::size_t z = 0;
    for (std::size_t ph = 0; ph < 3; ++ph) {
      if (modes.conduct[ph] == 0) {
        ++blocked;
        z = ph;
      }
    }
    if (blocked == 0) {
      return;
    }
    if (blocked >= 2) {
      // No line EMF can reach the bus: skip the probe (the common case when coasting).
      const double line_emf_bound = std::sqrt(3.0) * std::abs(p * x.omega_m_rad_s) *
                                    psi_m_Wb * emf.peak_bound();
      const double speed_bound = ideal_dyno ? std::abs(speed_reference(t).first) : 0.0;
      const double bus_min = bus_level_V *
                             (1.0 - (cfg.inverter.dc_ripple_enabled ? cfg.inverter.dc_ripple_fraction : 0.0));
      const double dyno_bound = std::sqrt(3.0) * p * speed_bound * psi_m_Wb * emf.peak_bound();
      if (std::max(line_emf_bound, dyno_bound) < bus_min) {
        return;
      }
    }
    State ds;
    Meters pw;
    Aux aux;
    evaluate(t, x, in, modes, ds, pw, aux);
    const double vdc = aux.dc_bus_V;
    if (blocked == 1) {
      // The floating phase starts conducting when its diode becomes forward biased.
      if (aux.blocked_pole_V > vdc + drop_V) {
        modes.conduct[z] = -1;
      } else if (aux.blocked_pole_V < -drop_V) {
        modes.conduct[z] = 1;
      }
      return;
    }
    // Uncontrolled rectification: the pair with the largest line EMF conducts once it
    // exceeds the bus plus two diode drops.
    double best = vdc + 2.0 * drop_V;
    int hi = -1;
    int lo = -1;
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) {
        const double diff =
            aux.e_abc_V[static_cast<std::size_t>(a)] - aux.e_abc_V[static_cast<std::size_t>(b)];
        if (a != b && diff > best) {
          best = diff;
          hi = a;
          lo = b;
        }
      }
    }
    if (hi >= 0) {
      modes.conduct = {0, 0, 0};
      modes.conduct[static_cast<std::size_t>(hi)] = -1;  // into the upper diode
      modes.conduct[static_cast<std::size_t>(lo)] = 1;   // out of the lower diode
    }
  }

  // Earliest fraction of a step at which a switching event happened (a sliding shaft
  // reversing, a conducting diode's current reaching zero), or none.
  struct Event {
    double fraction = 2.0;
    bool speed = false;
    std::array<bool, 3> phase{};
  };

  // The bridge's pole voltage is piecewise linear in a phase's current: the dead time and the
  // drop follow clamp(i / band, -1, 1), whose slope jumps at i = ±band, and a duty within the
  // dead time of 0 or 1 is clamped by the rail at a third current. RK4 keeps its order only
  // where the derivative is smooth: a step across such a kink is accurate to second order at
  // best, and at rated speed, where a phase crosses its band every few periods, that error
  // read as a 0.02 % (4 steps a period) to 0.5 % (one) resistance error in a bipolar pair
  // (plant_physics.OneStepPerPeriodAgreesWithAFineIntegration). So the step is split where a
  // phase's current crosses a kink (located by linear interpolation in a trial step) and
  // each piece is smooth. Up to four per phase; fixed for the period (they depend on the duty).
  struct Kinks {
    std::array<std::array<double, 4>, 3> at_A{};
    std::array<int, 3> count{};
  };

  [[nodiscard]] Kinks kinks_for(const PeriodInput& in) const {
    Kinks kinks;
    if (in.drive != Drive::pwm || (dead_time_fraction <= 0.0 && drop_V <= 0.0)) {
      return kinks;
    }
    for (std::size_t ph = 0; ph < 3; ++ph) {
      auto& at = kinks.at_A[ph];
      int& n = kinks.count[ph];
      at[static_cast<std::size_t>(n++)] = -band_A;
      at[static_cast<std::size_t>(n++)] = band_A;
      if (dead_time_fraction > 0.0) {
        // duty - f·sgn leaves [0, 1] where sgn passes duty / f or (duty - 1) / f.
        const double lo = band_A * in.duty[ph] / dead_time_fraction;
        const double hi = band_A * (in.duty[ph] - 1.0) / dead_time_fraction;
        if (std::abs(lo) < band_A) {
          at[static_cast<std::size_t>(n++)] = lo;
        }
        if (std::abs(hi) < band_A) {
          at[static_cast<std::size_t>(n++)] = hi;
        }
      }
    }
    return kinks;
  }

  // Earliest fraction of the step (phase currents i0 -> state s1) at which a phase current
  // crosses a kink, beyond the first thousandth of the step (a step that starts on a kink, as
  // the one after a split does, is not split again at its start), or 2 for none.
  [[nodiscard]] double find_kink(const Kinks& kinks, const std::array<double, 3>& i0,
                                const State& s1) const {
    double first = 2.0;
    if (kinks.count[0] == 0) {
      return first;
    }
    // Where the step ends the next one starts, and the sample is taken: motion() there reuses it.
    kept_trig_theta_e = p * s1.theta_m_rad;
    kept_trig = trig3(kept_trig_theta_e);
    const auto i1 = currents_abc(s1.id_A, s1.iq_A, kept_trig);
    constexpr double kMinFraction = 1e-3;
    for (std::size_t ph = 0; ph < 3; ++ph) {
      for (int j = 0; j < kinks.count[ph]; ++j) {
        const double b = kinks.at_A[ph][static_cast<std::size_t>(j)];
        const double a0 = i0[ph] - b;
        const double a1 = i1[ph] - b;
        if ((a0 < 0.0) != (a1 < 0.0) && a0 != a1) {
          const double f = a0 / (a0 - a1);
          if (f > kMinFraction && f < first) {
            first = f;
          }
        }
      }
    }
    return first;
  }

  Event find_event(const State& s0, const State& s1, const PeriodInput& in) const {
    Event ev;
    auto consider = [&](double v0, double v1, double sgn) -> std::optional<double> {
      if (sgn * v1 < 0.0) {
        const double f = (sgn * v0 > 0.0) ? v0 / (v0 - v1) : 0.0;
        return std::clamp(f, 0.0, 1.0);
      }
      return std::nullopt;
    };
    if (modes.mech == Mech::sliding) {
      if (auto f = consider(s0.omega_m_rad_s, s1.omega_m_rad_s, modes.slide_sign)) {
        ev.fraction = *f;
        ev.speed = true;
      }
    }
    if (in.drive == Drive::off) {
      const auto i0 = currents_abc(s0.id_A, s0.iq_A, trig3(p * s0.theta_m_rad));
      const auto i1 = currents_abc(s1.id_A, s1.iq_A, trig3(p * s1.theta_m_rad));
      for (std::size_t ph = 0; ph < 3; ++ph) {
        if (modes.conduct[ph] == 0) {
          continue;
        }
        if (auto f = consider(i0[ph], i1[ph], static_cast<double>(modes.conduct[ph]))) {
          if (*f < ev.fraction - 1e-9) {
            ev = Event{};
            ev.fraction = *f;
          }
          if (*f <= ev.fraction + 1e-9) {
            ev.phase[ph] = true;
          }
        }
      }
    }
    return ev;
  }

  void apply_event(const Event& ev) {
    if (ev.speed) {
      x.omega_m_rad_s = 0.0;
    }
    bool any_phase = false;
    for (std::size_t ph = 0; ph < 3; ++ph) {
      if (ev.phase[ph]) {
        modes.conduct[ph] = 0;
        any_phase = true;
      }
    }
    if (any_phase) {
      enforce_blocked();
    }
  }

  // Simulates [t_k, t_k + Ts) with the given input.
  void simulate_period(const PeriodInput& in) {
    sample_aux_valid = false;
    if (in.drive == Drive::off) {
      if (!conduction_valid) {
        init_conduction();
      }
    } else {
      conduction_valid = false;
      modes.conduct = {0, 0, 0};
    }
    const double t_start = static_cast<double>(k) * Ts_s;
    const double t_end = static_cast<double>(k + 1) * Ts_s;
    const Meters start = meters;
    double t = t_start;
    const Kinks kinks = kinks_for(in);
    int events = 0;
    constexpr int kMaxEventsPerPeriod = 64;
    // With the gates off a blocked phase starts to conduct only where a step starts
    // (decide_modes): that keeps steps of at most a quarter period, as the plant had before one
    // step a period became the default. (A stuck shaft, too, breaks away only where a step
    // starts: within a period of the moment, which a holding drive does not notice.)
    // A step turns the rotor frame by at most max_step_angle_rad: RK4's error grows as the fourth
    // power of that angle, and at rated speed with the field weakened one step a period read
    // 3e-4 of Rs on the reference (0.094 rad a period) and 1.2e-3 on the 30 mOhm IPM (0.126 rad).
    const double turn_rad = std::abs(p * x.omega_m_rad_s) * Ts_s;
    const double steps = std::ceil(turn_rad / cfg.simulation.max_step_angle_rad);
    double h_max = steps > 1.0 ? std::min(h_nominal_s, Ts_s / std::min(steps, 64.0)) : h_nominal_s;
    if (in.drive == Drive::off) {
      h_max = std::min(h_max, 0.25 * Ts_s);
    }
    while (t < t_end) {
      const double h = std::min(h_max, t_end - t);
      if (h <= 1e-12 * Ts_s) {
        break;
      }
      decide_modes(t, in);
      State s1;
      Meters dm;
      std::array<double, 3> i0{};
      rk4(t, x, h, in, modes, s1, dm, &i0);
      if (events < kMaxEventsPerPeriod) {
        Event ev = find_event(x, s1, in);
        const double kink = find_kink(kinks, i0, s1);
        if (kink < ev.fraction) {
          // No mode changes at a kink: the step ends there and the next starts on it.
          ev = Event{};
          ev.fraction = kink;
        }
        if (ev.fraction <= 1.0) {
          ++events;
          const double h_event = h * ev.fraction;
          if (h_event > 0.0) {
            rk4(t, x, h_event, in, modes, s1, dm);
            x = s1;
            meters.add(dm, 1.0);
          }
          t += h_event;
          apply_event(ev);
          continue;
        }
      }
      x = s1;
      meters.add(dm, 1.0);
      t += h;
    }
    if (ideal_dyno) {
      x.omega_m_rad_s = speed_reference(t_end).first;
    }
    copper_loss_W = (meters.copper_J - start.copper_J) / Ts_s;
    iron_loss_W = (meters.iron_J - start.iron_J) / Ts_s;
    friction_loss_W = (meters.friction_J - start.friction_J) / Ts_s;
    for (std::size_t ph = 0; ph < 3; ++ph) {
      v_avg_V[ph] = (meters.v_int_V_s[ph] - start.v_int_V_s[ph]) / Ts_s;
    }
    ++k;
    if (bus_moves) {
      update_bus_level(t_end, (meters.input_J - start.input_J) / Ts_s);
    }

    if (cfg.thermal.enabled) {
      const double fr = cfg.iron_loss.rotor_fraction;
      ThermalNetwork::Vector loss{
          copper_loss_W,
          (1.0 - fr) * iron_loss_W + cfg.thermal.friction_heat_fraction * friction_loss_W,
          fr * iron_loss_W};
      if (cfg.thermal.fan_speed_rad_s > 0.0) {
        // A shaft fan: the network's path holds housing_to_ambient_K_W (the fan's speed); what
        // this period's speed adds or takes enters the housing as a heat flow at the step's start
        // temperature (a step far below the housing's time constant: 4 ms of thermal time a period
        // at 40x and 10 kHz against minutes).
        const double extra_W_K =
            (ThermalNetwork::fan_share(cfg.thermal, x.omega_m_rad_s) - 1.0) / cfg.thermal.housing_to_ambient_K_W;
        loss[ThermalNetwork::kHousing] += extra_W_K * (ambient_C - thermal.temperatures_C()[ThermalNetwork::kHousing]);
      }
      thermal.step(loss, ambient_C);
      update_temperature_parameters();
    }
  }

  // Modes for evaluating the state at a sample instant (no integration follows).
  void sync_modes_for_sample() {
    if (ideal_dyno) {
      modes.mech = Mech::ideal_dyno;
    } else if (x.omega_m_rad_s == 0.0) {
      modes.mech = Mech::stuck;
    } else {
      modes.mech = Mech::sliding;
      modes.slide_sign = sign_of(x.omega_m_rad_s);
    }
    shaft_stuck = modes.mech == Mech::stuck;
  }

  void evaluate_aux(double t, Aux& aux) const {
    State ds;
    Meters pw;
    PeriodInput in;
    in.drive = gates_now ? Drive::pwm : Drive::off;
    in.duty = {0.5, 0.5, 0.5};
    Modes m = modes;
    if (in.drive == Drive::off && !conduction_valid) {
      m.conduct = {0, 0, 0};
    }
    evaluate_at_start(t, x, in, m, ds, pw, aux);
  }

  double noise(bool enabled, double sigma) {
    return (enabled && sigma > 0.0) ? sigma * rng.standard_normal() : 0.0;
  }

  // Sample k: what the controller's ADCs and encoder read at t_k.
  void take_sample(const Aux& aux, bool voltage_valid) {
    hal::SensorSample out{};
    out.sequence = static_cast<std::uint32_t>(k);
    out.pwm_period_code = period_code;
    const auto& adc = cfg.current_adc;
    const double full = current_full_codes;
    for (std::size_t ph = 0; ph < 3; ++ph) {
      const double gain = 1.0 + (adc.gain_error_enabled ? adc.gain_error[ph] : 0.0);
      const double offset = adc.offset_enabled ? adc.offset_A[ph] : 0.0;
      const double measured = aux.i_abc_A[ph] * gain + offset + noise(adc.noise_enabled, adc.noise_A);
      out.phase_current_adc[ph] = clamp_code<std::int16_t>(measured / current_lsb_A, -full, full - 1.0);
    }
    double angle = math::fmod_two_pi(x.theta_m_rad - cfg.encoder.offset_rad);
    if (angle < 0.0) {
      angle += kTwoPi;
    }
    double count = std::floor(angle / kTwoPi * encoder_counts);
    if (!(count >= 0.0 && count < encoder_counts)) {
      count = 0.0;  // also a diverged model's NaN: never cast to an integer
    }
    out.encoder_count = static_cast<std::uint16_t>(count);
    const double vdc = aux.dc_bus_V + noise(cfg.dc_bus_adc.noise_enabled, cfg.dc_bus_adc.noise_V);
    out.dc_bus_adc = clamp_code<std::uint16_t>(vdc / dc_lsb_V, 0.0,
                                               dc_max_code);
    const auto& pvs = cfg.phase_voltage_sensing;
    if (pvs.enabled && voltage_valid) {
      const double vfull = voltage_full_codes;
      for (std::size_t ph = 0; ph < 3; ++ph) {
        const double v = v_avg_V[ph] + noise(pvs.noise_enabled, pvs.noise_V);
        out.phase_voltage_adc[ph] = clamp_code<std::int16_t>(v / voltage_lsb_V, -vfull, vfull - 1.0);
      }
      out.flags |= hal::kSensorPhaseVoltageValid;
    }
    // The drive's ambient / coolant sensor (a digital sensor: 0.01 C steps), off by its offset.
    const double sensed_ambient_C = ambient_C + cfg.thermal.ambient_sensor_offset_C;
    out.ambient_centi_C =
        static_cast<std::int16_t>(std::clamp(std::round(sensed_ambient_C * 100.0), -32768.0, 32767.0));
    out.flags |= hal::kSensorAmbientValid;
    if (cfg.inverter.overcurrent_trip_enabled) {
      for (double i : aux.i_abc_A) {
        if (std::abs(i) > cfg.inverter.overcurrent_trip_A && !tripped) {
          tripped = true;
          trip_sample = k;
        }
      }
    }
    sample = out;
  }

  void finish_sample(bool voltage_valid) {
    sync_modes_for_sample();
    evaluate_aux(static_cast<double>(k) * Ts_s, sample_aux);
    sample_aux_valid = true;
    sample_aux_gates = gates_now;
    take_sample(sample_aux, voltage_valid);
  }

  void set_flags() {
    sample.flags = static_cast<std::uint8_t>(sample.flags & (hal::kSensorPhaseVoltageValid | hal::kSensorAmbientValid));
    if (gates_now) {
      sample.flags = static_cast<std::uint8_t>(sample.flags | hal::kSensorOutputEnabled);
    }
    if (tripped) {
      sample.flags = static_cast<std::uint8_t>(sample.flags | hal::kSensorHardwareOvercurrent);
    }
  }

  PeriodInput input_for(const hal::InverterCommand& cmd) const {
    PeriodInput in;
    in.drive = (cmd.enable && !tripped) ? Drive::pwm : Drive::off;
    for (std::size_t ph = 0; ph < 3; ++ph) {
      in.duty[ph] = static_cast<double>(cmd.duty[ph]) / hal::kDutyFullScale;
    }
    return in;
  }

  const hal::SensorSample& step(const hal::InverterCommand& cmd) {
    if (cmd.sequence != static_cast<std::uint32_t>(k)) {
      ++sequence_errors;
    }
    const bool delayed = cfg.inverter.computation_delay_periods == 1;
    const PeriodInput in = input_for(delayed ? latched : cmd);
    simulate_period(in);
    check_finite();
    // A disabling command computed after the trip was reported acknowledges it and clears
    // the latch for the following periods.
    if (tripped && !cmd.enable && cmd.sequence >= trip_sample) {
      tripped = false;
    }
    if (delayed) {
      latched = cmd;
      gates_now = latched.enable && !tripped;
    } else {
      gates_now = in.drive == Drive::pwm;
    }
    finish_sample(true);
    if (delayed) {
      gates_now = latched.enable && !tripped;  // a trip at this sample already opens the gates
    }
    set_flags();
    return sample;
  }

  const hal::SensorSample& step_dq(double vd_V, double vq_V) {
    PeriodInput in;
    in.drive = Drive::dq;
    in.vd_V = vd_V;
    in.vq_V = vq_V;
    simulate_period(in);
    check_finite();
    finish_sample(true);
    set_flags();
    return sample;
  }

  PlantState make_state() const {
    Aux evaluated;
    const Aux* kept = &sample_aux;
    if (!(sample_aux_valid && sample_aux_gates == gates_now)) {
      evaluate_aux(static_cast<double>(k) * Ts_s, evaluated);
      kept = &evaluated;
    }
    const Aux& aux = *kept;
    PlantState s;
    s.time_s = static_cast<double>(k) * Ts_s;
    s.id_A = x.id_A;
    s.iq_A = x.iq_A;
    s.phase_current_A = aux.i_abc_A;
    s.theta_m_rad = math::fmod_two_pi(x.theta_m_rad);
    if (s.theta_m_rad < 0.0) {
      s.theta_m_rad += kTwoPi;
    }
    s.theta_e_rad = math::fmod_two_pi(p * s.theta_m_rad);
    s.omega_m_rad_s = aux.omega_m_rad_s;
    s.omega_e_rad_s = p * aux.omega_m_rad_s;
    s.phase_emf_V = aux.e_abc_V;
    s.psi_m_Wb = psi_m_Wb;
    s.rs_ohm = rs_ohm;
    const auto& t = thermal.temperatures_C();
    s.winding_temp_C = t[ThermalNetwork::kWinding];
    s.housing_temp_C = t[ThermalNetwork::kHousing];
    s.magnet_temp_C = t[ThermalNetwork::kRotor];
    s.ambient_C = ambient_C;
    s.torque_em_Nm = aux.torque_em_Nm;
    s.cogging_torque_Nm = aux.torque_cog_Nm;
    s.load_torque_Nm = aux.torque_load_Nm;
    s.dc_bus_V = aux.dc_bus_V;
    s.phase_voltage_avg_V = v_avg_V;
    s.copper_loss_W = copper_loss_W;
    s.iron_loss_W = iron_loss_W;
    s.friction_loss_W = friction_loss_W;
    s.gates_enabled = gates_now;
    s.overcurrent_tripped = tripped;
    s.shaft_stuck = shaft_stuck;
    s.energy = EnergyMeters{meters.input_J, meters.copper_J, meters.iron_J, meters.friction_J,
                            meters.load_J, meters.cable_J};
    return s;
  }
};

Plant::Plant(const PlantConfig& config) : impl_(std::make_unique<Impl>(config)) {}
Plant::~Plant() = default;
Plant::Plant(Plant&&) noexcept = default;
// A copy carries on from the same state, its noise generator's included: stepped with the same
// commands, it gives the same samples (the simulator forks its twin so).
Plant::Plant(const Plant& other) : impl_(std::make_unique<Impl>(*other.impl_)) {}
Plant& Plant::operator=(const Plant& other) {
  if (this == &other) {
    return *this;
  }
  if (impl_) {
    *impl_ = *other.impl_;  // the configuration's vectors keep their capacity: no allocation after the first
  } else {
    impl_ = std::make_unique<Impl>(*other.impl_);  // a moved-from plant
  }
  return *this;
}
Plant& Plant::operator=(Plant&&) noexcept = default;

const hal::SensorSample& Plant::sample() const { return impl_->sample; }

const hal::SensorSample& Plant::step(const hal::InverterCommand& cmd) { return impl_->step(cmd); }

const hal::SensorSample& Plant::step_with_dq_voltage(double vd_V, double vq_V) {
  return impl_->step_dq(vd_V, vq_V);
}

hal::TruthSample Plant::truth() const {
  const PlantState s = impl_->make_state();
  hal::TruthSample t;
  t.sequence = static_cast<std::uint32_t>(impl_->k);
  t.winding_temp_C = static_cast<float>(s.winding_temp_C);
  t.housing_temp_C = static_cast<float>(s.housing_temp_C);
  t.magnet_temp_C = static_cast<float>(s.magnet_temp_C);
  t.rs_ohm = static_cast<float>(s.rs_ohm);
  t.torque_Nm = static_cast<float>(s.torque_em_Nm);
  t.speed_rad_s = static_cast<float>(s.omega_m_rad_s);
  t.load_torque_Nm = static_cast<float>(s.load_torque_Nm);
  t.copper_loss_W = static_cast<float>(s.copper_loss_W);
  t.iron_loss_W = static_cast<float>(s.iron_loss_W);
  return t;
}

PlantState Plant::state() const { return impl_->make_state(); }

double Plant::time_s() const { return static_cast<double>(impl_->k) * impl_->Ts_s; }
std::uint32_t Plant::period() const { return static_cast<std::uint32_t>(impl_->k); }
double Plant::period_s() const { return impl_->Ts_s; }
const PlantConfig& Plant::config() const { return impl_->cfg; }
std::uint64_t Plant::command_sequence_errors() const { return impl_->sequence_errors; }

bool Plant::diverged() const { return impl_->diverged_at_s >= 0.0; }

double Plant::diverged_at_s() const { return impl_->diverged_at_s; }

void Plant::set_ambient_C(double ambient_C) { impl_->ambient_C = ambient_C; }

void Plant::set_thermal_acceleration(double acceleration) {
  Impl& im = *impl_;
  ThermalNetwork network(im.cfg.thermal, acceleration / im.cfg.inverter.pwm_frequency_Hz);
  network.set_temperatures_C(im.thermal.temperatures_C());
  im.thermal = network;
}

void Plant::set_temperatures_C(double winding_C, double housing_C, double rotor_C) {
  impl_->thermal.set_temperatures_C({winding_C, housing_C, rotor_C});
  impl_->update_temperature_parameters();
  impl_->invalidate_evaluations();
}

void Plant::set_load_torque_Nm(double torque_Nm) {
  Impl& im = *impl_;
  im.cfg.load.profile = LoadProfile::constant_torque;
  im.cfg.load.torque_Nm = torque_Nm;
  im.cfg.load.points.clear();  // keeps the capacity: no deallocation on the RT side
  im.configure_dyno();
  im.invalidate_evaluations();
}

void Plant::set_imposed_speed_rad_s(double speed_rad_s) {
  Impl& im = *impl_;
  im.cfg.load.profile = LoadProfile::speed_cycle;
  im.cfg.load.speed_rad_s = speed_rad_s;
  im.cfg.load.points.clear();
  im.configure_dyno();
  if (im.ideal_dyno) {
    im.x.omega_m_rad_s = speed_rad_s;
  } else {
    im.x.dyno_int_rad = 0.0;
  }
  im.invalidate_evaluations();
}

}  // namespace pmsm::plant
