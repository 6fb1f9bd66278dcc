// `pmsm-thermal budget` and `pmsm-thermal losses`: the commissioning engineer's questions
// "how much injection current can I afford, and what does it cost" (paper Sections VII-VIII).
#include <cmath>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>

#include <fmt/core.h>
#include <toml++/toml.h>

#include "json_writer.hpp"
#include "commands.hpp"
#include "cli_validators.hpp"
#include "config_schema.hpp"
#include "controller_config.hpp"
#include "pmsm/core/current_controller.hpp"
#include "pmsm/core/injection.hpp"
#include "pmsm/core/injection_scheduler.hpp"
#include "pmsm/core/motor_params.hpp"
#include "pmsm/core/window.hpp"

namespace pmsm::app {
namespace {


// Upper bounds of the planning options: generous for any industrial PMSM, finite so that no
// answer is printed as inf or nan.
constexpr double kMaxInductance_H = 10.0;
// ... and lower bounds below every real machine, for the same reason: with --Ld and --Rs of
// 1e-200 the largest F was printed as "inf A".
constexpr double kMinInductance_H = common::kMinInductance_H;
constexpr double kMinResistance_ohm = common::kMinStatorResistance_ohm;
constexpr double kMaxWindow_s = 10.0;
constexpr double kMaxVoltage_V = 100e3;
constexpr double kMaxCurrent_A = 100e3;
constexpr double kMaxSpeed_rad_s = 10e3;  // mechanical, ~95,000 rpm
constexpr double kMaxKe = 1000.0;
constexpr double kMaxTime_s = 1e9;
// The shortest window a drive can shape (a microsecond: ten PWM periods at 10 MHz): shorter,
// the slope's voltage overflows into inf (--Tw 1e-300 printed "voltage required inf V").
constexpr double kMinWindow_s = 1e-6;
constexpr double kMinRatedPower_W = 1.0;

core::WindowKind window_from_name(const std::string& name) {
  return name == "modified" ? core::WindowKind::kModifiedBlackman : core::WindowKind::kBlackman;
}

// The defaults are the drive's own (core::MotorParams, core::InjectionConfig: what
// pmsm-thermald runs with no key set), so that a plan without options is the drive's plan.
// Fig. 8 of the paper is --Ld 0.009 --Tw 0.01 --window blackman.
struct BudgetOptions {
  double ld_H = core::MotorParams{}.ld_H;
  double lq_H = 0.0;    // 0: equal to Ld
  double rs_ohm = core::MotorParams{}.rs_ohm;
  double tw_s = core::InjectionConfig{}.tw_s;
  std::string window_name{core::to_string(core::InjectionConfig{}.window)};
  core::WindowKind window = core::InjectionConfig{}.window;
  double voltage_V = 0.0;
  double current_A = 0.0;
  double speed_rad_s = 0.0;
  double iq_A = 0.0;
  double vdc_V = core::kReferenceDcBus_V;
  double voltage_fraction = core::CurrentControllerConfig{}.voltage_limit_fraction;
  std::optional<double> margin_V;  // unset: the drive's default, 15 V at 650 V, following the bus
  double max_torque_Nm = core::InjectionConfig{}.max_torque_disturbance_Nm;  // 0: no torque budget
  double current_limit_A = 0.0;  // 0: none (the F printed is the voltage's and the torque's)
  // The pulses the current limit is applied to: fixed-magnitude (|(+-F, iq)| within it), or a
  // vector turning relative to the rotor (fixed-angle, DC: F within limit - |i|), as the
  // scheduler applies it; from --config the drive's injection.method.
  bool turning_vector = false;
  std::string config_path;  // a drive's configuration: every option not given comes from it
  double ke_V_s_per_rad = core::MotorParams{}.ke_V_s_per_rad;
  int pole_pairs = core::MotorParams{}.pole_pairs;
  bool json = false;
};

struct LossOptions {
  double rated_power_W = core::MotorParams{}.rated_power_W;
  std::string window_name = "blackman";
  std::string method = "fixed-magnitude";
  core::InjectionSchedule schedule{};
  double omega_e_rad_s = 0.0;
  bool omega_given = false;
  bool json = false;
};

void add_window_option(CLI::App* cmd, std::string& window_name) {
  cmd->add_option("--window", window_name, "window function: blackman (Eq. 23) or modified (Eq. 24)")
      ->check(CLI::IsMember({"blackman", "modified"}))
      ->capture_default_str();
}

// The options a drive's configuration gives (its [controller] section, parsed and checked as
// pmsm-thermald parses and checks it; the file's other sections are not read): every one the
// command line does not. The q-axis inductance is the commissioned secant at --iq (the flux
// map's, core::LqShape, where the configuration has one). The margin is the file's
// injection.headroom_margin_V where it gives one, else the drive's default at the bus planned
// with (--vdc, or the file's control.nominal_dc_bus_V). Throws ConfigError.
void apply_drive_configuration(BudgetOptions& o, const CLI::App& cmd) {
  const toml::table root = common::parse_toml(common::read_config_file(o.config_path, "--config"), o.config_path);
  const toml::table* section = common::optional_section(root, "controller", o.config_path);
  if (section == nullptr) {
    // A file with no drive in it (or a misspelt section) would plan the default motor.
    throw ConfigError(o.config_path + ": no [controller] section: not a drive's configuration (pmsm-thermald's axis "
                                      "file keeps the drive under [controller.motor], [controller.control], ...)");
  }
  const ControllerConfig c = parse_controller_config(*section, o.config_path, {}, "controller.");
  const core::DriveConfig& d = c.drive;
  auto unset = [&cmd](const char* flag) { return cmd.count(flag) == 0; };
  if (unset("--Ld")) o.ld_H = d.motor.ld_H;
  if (unset("--Rs")) o.rs_ohm = core::terminal_resistance_ohm(d);  // the nameplate's and a motor cable's
  if (unset("--Tw")) o.tw_s = d.injection.tw_s;
  if (unset("--window")) o.window = d.injection.window;
  if (unset("--vdc")) o.vdc_V = c.nominal_dc_bus_V;
  if (unset("--voltage-fraction")) o.voltage_fraction = d.current.voltage_limit_fraction;
  if (unset("--margin") && c.relative.headroom_margin_V) o.margin_V = *c.relative.headroom_margin_V;
  if (unset("--Ke")) o.ke_V_s_per_rad = d.motor.ke_V_s_per_rad;
  if (unset("--pole-pairs")) o.pole_pairs = d.motor.pole_pairs;
  if (unset("--max-torque-disturbance")) o.max_torque_Nm = d.injection.max_torque_disturbance_Nm;
  if (unset("--current-limit")) o.current_limit_A = d.injection.current_limit_A;
  o.turning_vector = d.injection.method != core::InjectionMethod::kFixedMagnitude;
  if (unset("--Lq")) o.lq_H = core::LqShape(d.injection).commissioned_secant_H(o.iq_A);
}

int run_budget(const BudgetOptions& o, const CLI::App& cmd) {
  const core::WindowConstants constants = core::compute_window_constants(o.window);
  const bool by_voltage = cmd.count("--voltage") > 0;
  const bool by_current = cmd.count("--current") > 0;
  const bool by_speed = cmd.count("--speed") > 0;

  JsonWriter json;
  json.begin_object()
      .field("window", core::to_string(o.window))
      .field("Tw_s", o.tw_s)
      .field("ld_H", o.ld_H)
      .field("rs_ohm", o.rs_ohm)
      .field("max_slope_per_Tw", constants.max_slope_times_tw)
      .field("window_integral_per_Tw", constants.integral_per_tw);
  if (!o.config_path.empty()) {
    json.field("config", o.config_path);
  }

  std::string text = fmt::format(
      "Injection budget: {} window, Tw = {:g} ms, Ld = {:g} mH, Rs = {:g} ohm\n"
      "  window max slope       {:.3f} / Tw   (Eqs. 25-26)\n"
      "  window integral        {:.3f} * Tw   (Eqs. 27-28)\n",
      core::to_string(o.window), o.tw_s * 1e3, o.ld_H * 1e3, o.rs_ohm, constants.max_slope_times_tw,
      constants.integral_per_tw);
  if (!o.config_path.empty()) {
    text += fmt::format("  drive configuration    {}   (every option not given)\n", o.config_path);
  }

  if (by_voltage) {
    const double f = core::max_injection_current_A(o.voltage_V, o.ld_H, o.rs_ohm, o.tw_s, o.window);
    json.field("voltage_V", o.voltage_V).field("max_injection_current_A", f)
        .field("per_phase_current_A", core::per_phase_injection_current_A(f));
    text += fmt::format(
        "  voltage available      {:.1f} V\n"
        "  largest injection F    {:.2f} A   (Eq. 29 inverted; per phase {:.2f} A, Eq. 30)\n",
        o.voltage_V, f, core::per_phase_injection_current_A(f));
  } else if (by_current) {
    const double v = core::required_injection_voltage_V(o.current_A, o.ld_H, o.rs_ohm, o.tw_s, o.window);
    json.field("current_A", o.current_A).field("required_voltage_V", v)
        .field("per_phase_current_A", core::per_phase_injection_current_A(o.current_A));
    text += fmt::format(
        "  injection F            {:.2f} A   (per phase {:.2f} A, Eq. 30)\n"
        "  voltage required       {:.2f} V   (Eq. 29)\n",
        o.current_A, core::per_phase_injection_current_A(o.current_A), v);
  } else if (by_speed) {
    core::InjectionHeadroomInput in;
    in.rs_ohm = o.rs_ohm;
    in.ld_H = o.ld_H;
    in.lq_H = o.lq_H > 0.0 ? o.lq_H : o.ld_H;
    core::MotorParams motor;
    motor.ke_V_s_per_rad = o.ke_V_s_per_rad;
    motor.pole_pairs = o.pole_pairs;
    in.flux_linkage_Wb = core::flux_linkage_Wb(motor);
    in.omega_e_rad_s = o.speed_rad_s * o.pole_pairs;
    in.iq_A = o.iq_A;
    // The drive keeps injection.headroom_margin_V of the limit free (15 V at a 650 V bus by
    // default, following the bus): the injection may use what is left.
    const double margin_V = o.margin_V.value_or(core::default_headroom_margin_V(o.vdc_V));
    in.voltage_limit_V = o.voltage_fraction * o.vdc_V / core::kSqrt3 - margin_V;
    if (!(in.voltage_limit_V > 0.0)) {
      std::fprintf(stderr,
                   "pmsm-thermal budget: the margin %g V takes the whole voltage limit at --vdc %g V (%g V = "
                   "--voltage-fraction x Vdc / sqrt(3)): no injection could ever be budgeted\n",
                   margin_V, o.vdc_V, o.voltage_fraction * o.vdc_V / core::kSqrt3);
      return 2;
    }
    in.tw_s = o.tw_s;
    in.window = o.window;
    const core::Dq v0 = core::motoring_voltage(in);
    const double f_pos = core::max_injection_current_at_operating_point_A(in, 1.0);
    const double f_neg = core::max_injection_current_at_operating_point_A(in, -1.0);
    const double motoring = std::hypot(v0.d, v0.q);
    // The torque budget (injection.max_torque_disturbance_Nm) on a salient machine: the pulse's
    // reluctance torque, as the drive's scheduler limits it.
    const double f_torque = core::max_injection_current_for_torque_A(o.max_torque_Nm, o.pole_pairs, in.ld_H, in.lq_H, o.iq_A);
    // The current limit (derating.max_current_A) that motoring and injection share, as the
    // scheduler applies it to fixed-magnitude pulses: |(id +- F, iq)| within it (id = 0 here).
    const bool current_limited = o.current_limit_A > 0.0;
    double f_current = std::numeric_limits<double>::infinity();
    if (current_limited) {
      f_current = std::min(
          core::max_injection_current_for_current_limit_A(o.current_limit_A, 0.0, o.iq_A, 1.0, o.turning_vector),
          core::max_injection_current_for_current_limit_A(o.current_limit_A, 0.0, o.iq_A, -1.0, o.turning_vector));
    }
    const double f_bipolar = std::min({f_pos, f_neg, f_torque, f_current});
    json.field("speed_rad_s", o.speed_rad_s).field("iq_A", o.iq_A).field("lq_H", in.lq_H).field("pole_pairs", o.pole_pairs)
        .field("vdc_V", o.vdc_V).field("margin_V", margin_V)
        .field("voltage_limit_V", in.voltage_limit_V).field("motoring_voltage_V", motoring)
        .field("voltage_headroom_V", in.voltage_limit_V - motoring)
        .field("max_positive_injection_current_A", f_pos)
        .field("max_negative_injection_current_A", f_neg)
        .field("max_torque_disturbance_Nm", o.max_torque_Nm);
    if (std::isfinite(f_torque)) {
      json.field("max_torque_injection_current_A", f_torque);
    }
    // The drive limits its motoring iq to the same limit: an --iq at or beyond it is not an
    // operating point the drive reaches (the plan says so instead of a bare F = 0).
    const bool iq_beyond_limit = current_limited && std::abs(o.iq_A) >= o.current_limit_A;
    if (current_limited) {
      json.field("current_limit_A", o.current_limit_A).field("max_current_injection_current_A", f_current)
          .field("iq_beyond_current_limit", iq_beyond_limit);
    }
    // A speed whose EMF alone passes the voltage limit at id = 0 is reached only in field
    // weakening, which this plan does not model: said, not a bare F = 0.
    const bool beyond_voltage = motoring > in.voltage_limit_V;
    json.field("max_injection_current_A", f_bipolar).field("motoring_beyond_voltage_limit", beyond_voltage);
    const std::string torque_line =
        std::isfinite(f_torque)
            ? fmt::format("  largest F for torque   {:.2f} A   (1.5 p |Ld - Lq| F |iq| within {:g} Nm)\n", f_torque,
                          o.max_torque_Nm)
            : std::string{};
    const std::string current_line =
        current_limited
            ? fmt::format("  largest F for current  {:.2f} A   ({} within the limit {:g} A)\n", f_current,
                          o.turning_vector ? "a turning vector: F + |iq|" : "|(+-F, iq)|", o.current_limit_A)
            : std::string{};
    const std::string beyond_line =
        iq_beyond_limit ? fmt::format("  note                   |iq| {:g} A is at or beyond the current limit {:g} A: the drive "
                                      "limits its motoring iq to it, and no injection fits\n",
                                      std::abs(o.iq_A), o.current_limit_A)
                        : std::string{};
    const std::string voltage_line =
        beyond_voltage
            ? fmt::format("  note                   the motoring voltage at id = 0 is {:.1f} V, beyond the {:.1f} V limit: "
                          "the drive reaches this speed only in field weakening (controller.field_weakening), which "
                          "this plan does not model, and no pulse fits at id = 0\n",
                          motoring, in.voltage_limit_V)
            : std::string{};
    std::string within = std::isfinite(f_torque) ? ", within the torque budget" : "";
    if (current_limited) {
      within += std::isfinite(f_torque) ? " and the current limit" : ", within the current limit";
    }
    text += fmt::format(
        "  operating point        {:.1f} rad/s mech, iq {:.1f} A, Vdc {:.0f} V, Lq {:g} mH, {} pole pairs\n"
        "  voltage limit          {:.1f} V   ({:.0f} % of Vdc/sqrt(3), less the margin {:.1f} V)\n"
        "  motoring voltage       {:.1f} V   (Eq. 3, steady state)\n"
        "  largest +F             {:.2f} A\n"
        "  largest -F             {:.2f} A\n"
        "{}{}"
        "  largest bipolar F      {:.2f} A   ({})\n"
        "{}{}",
        o.speed_rad_s, o.iq_A, o.vdc_V, in.lq_H * 1e3, o.pole_pairs, in.voltage_limit_V, o.voltage_fraction * 100.0, margin_V, motoring,
        f_pos, f_neg, torque_line, current_line, f_bipolar,
        f_bipolar > 0.0 ? "+F and -F both fit" + within : std::string("no pulse fits"), beyond_line, voltage_line);
  }
  json.end_object();
  std::printf("%s\n", o.json ? json.str().c_str() : text.c_str());
  return 0;
}

int run_losses(const LossOptions& o) {
  const bool fixed_angle = o.method == "fixed-angle";
  if (fixed_angle && !o.omega_given) {
    std::fprintf(stderr, "losses: --omega is required for --method fixed-angle (Eq. 31 depends on the electrical speed)\n");
    return 2;
  }
  // (A rule on --method's value, so not CLI11's needs() as budget's options have.)
  if (!fixed_angle && o.omega_given) {
    std::fprintf(stderr, "losses: --omega applies to --method fixed-angle only (Eq. 32's loss does not depend on the speed)\n");
    return 2;
  }
  const core::InjectionSchedule& s = o.schedule;
  // Ninj pulses of Ti + 2 Tw each (rising edge Tw, flat top Ti, falling edge Tw) must fit in Tel: beyond
  // that Eqs. 31-32 average a loss over less time than the pulses take (a duty above 100 %).
  const double pulse_s = core::PulseEnvelope{s.window, s.tw_s, s.ti_s}.duration_s();
  if (s.pulses * pulse_s > s.elapsed_s) {
    std::fprintf(stderr,
                 "losses: --pulses %d of Ti + 2 Tw = %g s each take %g s, more than --elapsed %g s; "
                 "give fewer or shorter pulses or a longer --elapsed\n",
                 s.pulses, pulse_s, s.pulses * pulse_s, s.elapsed_s);
    return 2;
  }
  // Eq. 31 integrates cos over one arc centred on theta_F; beyond half a turn the integral of
  // cos (rather than cos^2) no longer measures dissipation, so say so rather than print it.
  const double arc_rad = o.omega_e_rad_s * s.ti_s;
  const bool arc_too_long = fixed_angle && arc_rad > core::kPi;
  if (arc_too_long) {
    std::fprintf(stderr,
                 "losses: warning: the fixed-angle arc w*Ti = %.1f deg exceeds 180 deg; Eq. 31 assumes one arc "
                 "centred on theta_F and understates the loss there; see average_loss_exact_W\n",
                 arc_rad * 180.0 / core::kPi);
  }
  const double paper = fixed_angle ? core::fixed_angle_average_loss_W(s, o.omega_e_rad_s)
                                   : core::fixed_magnitude_average_loss_W(s);
  const double exact = fixed_angle ? core::fixed_angle_average_loss_exact_W(s, o.omega_e_rad_s)
                                   : core::fixed_magnitude_average_loss_exact_W(s);
  const double rated_W = o.rated_power_W;
  if (o.json) {
    JsonWriter json;
    json.begin_object()
        .field("method", o.method)
        .field("equation", fixed_angle ? "Eq. 31" : "Eq. 32")
        .field("F_A", s.f_A).field("rs_ohm", s.rs_ohm).field("pulses", s.pulses)
        .field("elapsed_s", s.elapsed_s).field("Ti_s", s.ti_s).field("Tw_s", s.tw_s)
        .field("window", core::to_string(s.window));
    if (fixed_angle) {
      json.field("omega_rad_s", o.omega_e_rad_s).field("arc_deg", arc_rad * 180.0 / core::kPi);
    }
    json.field("average_loss_W", paper)
        .field("average_loss_exact_W", exact)
        .field("fraction_of_rated_power", paper / rated_W)
        .end_object();
    std::printf("%s\n", json.str().c_str());
    return 0;
  }
  std::printf(
      "Injection losses: %s, F = %g A, Rs = %g ohm, %d pulses every %g s, Ti = %g ms, Tw = %g ms (%s)\n"
      "  average loss           %.3f W   (%s as printed in the paper)\n"
      "  average loss, exact    %.3f W   (integral of 3/2 Rs i^2; see docs/equations.md)\n"
      "  share of rated power   %.4f %%  (of %.1f kW, --rated-power)\n",
      o.method.c_str(), s.f_A, s.rs_ohm, s.pulses, s.elapsed_s, s.ti_s * 1e3, s.tw_s * 1e3,
      std::string(core::to_string(s.window)).c_str(), paper, fixed_angle ? "Eq. 31" : "Eq. 32", exact,
      100.0 * paper / rated_W, rated_W / 1e3);
  return 0;
}

}  // namespace

void register_budget_command(CLI::App& app, int& exit_code) {
  auto options = std::make_shared<BudgetOptions>();
  CLI::App* cmd = app.add_subcommand(
      "budget", "Largest injection current for a voltage headroom, or voltage for a current (Eqs. 29-30)");
  cmd->add_option("--Ld", options->ld_H, "d-axis inductance, H")->check(cli::number_in_range(kMinInductance_H, kMaxInductance_H))->capture_default_str();
  cmd->add_option("--Rs", options->rs_ohm, "stator resistance, ohm (phase to neutral)")->check(cli::number_in_range(kMinResistance_ohm, common::kMaxStatorResistance_ohm))->capture_default_str();
  cmd->add_option("--Tw", options->tw_s, "window period, s")->check(cli::number_in_range(kMinWindow_s, kMaxWindow_s))->capture_default_str();
  add_window_option(cmd, options->window_name);
  auto* mode = cmd->add_option_group("mode", "what to compute (exactly one)");
  mode->add_option("--voltage", options->voltage_V, "voltage available for injection, V")->check(cli::positive(kMaxVoltage_V));
  mode->add_option("--current", options->current_A, "injection current F, A")->check(cli::positive(kMaxCurrent_A));
  CLI::Option* speed = mode->add_option("--speed", options->speed_rad_s, "mechanical speed, rad/s: largest F at this operating point")
                           ->check(cli::non_negative(kMaxSpeed_rad_s));
  mode->require_option(1);
  // The operating point's options mean nothing to --voltage or --current: given there they
  // would be ignored without a word, so CLI11 refuses them ("--iq requires --speed").
  cmd->add_option("--Lq", options->lq_H, "q-axis inductance, H (default: equal to Ld; with --config the configuration's secant at --iq)")->check(cli::number_in_range(kMinInductance_H, kMaxInductance_H))->needs(speed);
  cmd->add_option("--iq", options->iq_A, "motoring q-axis current, A peak")
      ->check(cli::number_in_range(-kMaxCurrent_A, kMaxCurrent_A))->capture_default_str()->needs(speed);
  cmd->add_option("--vdc", options->vdc_V, "DC-bus voltage, V")->check(cli::number_in_range(common::kMinDcBus_V, kMaxVoltage_V))->capture_default_str()->needs(speed);
  cmd->add_option("--voltage-fraction", options->voltage_fraction, "usable fraction of Vdc/sqrt(3)")
      ->check(cli::number_in_range(0.1, 1.0))->capture_default_str()->needs(speed);
  cmd->add_option("--margin", options->margin_V,
                  "voltage kept free of the limit, V (injection.headroom_margin_V; default the drive's, 15 V at 650 V "
                  "scaled with --vdc)")
      ->check(cli::non_negative(kMaxVoltage_V))->needs(speed);
  cmd->add_option("--max-torque-disturbance", options->max_torque_Nm,
                  "torque budget of the pulse's reluctance torque, Nm (injection.max_torque_disturbance_Nm; 0: none)")
      ->check(cli::non_negative(10000))->capture_default_str()->needs(speed);
  cmd->add_option("--current-limit", options->current_limit_A,
                  "current limit shared by motoring and injection, A peak (derating.max_current_A; 0: none)")
      ->check(cli::non_negative(kMaxCurrent_A))->capture_default_str()->needs(speed);
  cmd->add_option("--Ke", options->ke_V_s_per_rad, "EMF constant, line-to-line RMS V per mechanical rad/s")
      ->check(cli::number_in_range(common::kMinEmfConstant_V_s_per_rad, kMaxKe))->capture_default_str()->needs(speed);
  cmd->add_option("--pole-pairs", options->pole_pairs, "pole pairs")->check(cli::integer_in_range(1, 64))->capture_default_str()->needs(speed);
  cmd->add_option("--config", options->config_path,
                  "a pmsm-thermald axis configuration (its [controller] section, checked as the daemon checks it): "
                  "the motor, bus, voltage fraction, margin, torque budget, current limit, window and Tw of every option not given "
                  "(flags win); Lq is its commissioned secant at --iq, the current limit its derating.max_current_A.")
      ->check(CLI::ExistingFile);
  cmd->add_flag("--json", options->json, "print one JSON object");
  cmd->callback([options, cmd, &exit_code] {
    options->window = window_from_name(options->window_name);
    if (!options->config_path.empty()) {
      try {
        apply_drive_configuration(*options, *cmd);
      } catch (const ConfigError& e) {
        std::fprintf(stderr, "pmsm-thermal budget: %s\n", e.what());
        exit_code = 2;
        return;
      }
    }
    exit_code = run_budget(*options, *cmd);
  });
}

void register_losses_command(CLI::App& app, int& exit_code) {
  auto options = std::make_shared<LossOptions>();
  CLI::App* cmd = app.add_subcommand("losses", "Average copper loss of periodic injection (Eqs. 31-32); the defaults are "
                                                      "the paper's example schedule (Blackman, Tw 10 ms), not the drive's");
  cmd->add_option("--method", options->method, "fixed-magnitude (Eq. 32) or fixed-angle (Eq. 31)")
      ->check(CLI::IsMember({"fixed-magnitude", "fixed-angle"}))->capture_default_str();
  core::InjectionSchedule& s = options->schedule;
  cmd->add_option("--F", s.f_A, "injection current magnitude, A")->check(cli::positive(kMaxCurrent_A))->required();
  cmd->add_option("--Rs", s.rs_ohm, "stator resistance, ohm")->check(cli::number_in_range(kMinResistance_ohm, common::kMaxStatorResistance_ohm))->capture_default_str();
  cmd->add_option("--pulses", s.pulses, "injection pulses in the elapsed time (Ninj)")->check(cli::integer_in_range(1, 1000000))->capture_default_str();
  cmd->add_option("--elapsed", s.elapsed_s, "elapsed time Tel, s")->check(cli::positive(kMaxTime_s))->capture_default_str();
  cmd->add_option("--Ti", s.ti_s, "duration of the flat top of one pulse, s")->check(cli::non_negative(kMaxTime_s))->capture_default_str();
  cmd->add_option("--Tw", s.tw_s, "window period, s")->check(cli::number_in_range(kMinWindow_s, kMaxWindow_s))->capture_default_str();
  add_window_option(cmd, options->window_name);
  cmd->add_option("--omega", options->omega_e_rad_s, "electrical speed, rad/s (fixed-angle)")->check(cli::non_negative(kMaxSpeed_rad_s * 100.0));
  cmd->add_option("--rated-power", options->rated_power_W, "the machine's rated power, W (the share printed; default Table I's)")
      ->check(cli::number_in_range(kMinRatedPower_W, 1e9))->capture_default_str();
  cmd->add_flag("--json", options->json, "print one JSON object");
  cmd->callback([options, cmd, &exit_code] {
    options->omega_given = cmd->count("--omega") > 0;
    options->schedule.window = window_from_name(options->window_name);
    exit_code = run_losses(*options);
  });
}

}  // namespace pmsm::app
