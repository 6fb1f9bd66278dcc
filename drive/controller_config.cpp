#include "controller_config.hpp"

#include "calibration_file.hpp"
#include "config_schema.hpp"
#include "pmsm/core/injection.hpp"
#include "pmsm/core/machine_equations.hpp"
#include "pmsm/core/speed_controller.hpp"
#include "pmsm/core/thermal_observer.hpp"
#include "text_file.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <numbers>
#include <string>
#include <system_error>
#include <tuple>

#include <fmt/format.h>

namespace pmsm::app {
namespace {

using core::EstimatorKind;
using core::InjectionMethod;
using core::Separation;
using core::WindowKind;
using C = ControllerConfig;

// A motor cable (at 20 C) that takes all of a calibration's Rs0 at its T0: the text of why, or
// empty. Eq. 1 would have no winding left (and a negative one turns its slope over).
std::string cable_leaves_no_winding(double cable_20C_ohm, const core::Calibration& cal) {
  const double cable_ohm = core::cable_resistance_at_C(cable_20C_ohm, cal.t0_C);
  if (!(cable_20C_ohm > 0.0) || cable_ohm < cal.rs0_ohm) {
    return {};
  }
  return fmt::format(" is {:.6g} ohm at {:.6g} C, not below the calibration's Rs0 ({:.6g} ohm), the whole resistance "
                     "the drive measures: it would leave no winding for Eq. 1",
                     cable_ohm, cal.t0_C, cal.rs0_ohm);
}

ConfigSchema<C> build() {
  ConfigSchema<C> s;
  // [motor] — the controller's commissioned model of the machine.
  s.real("motor.rs_ohm", [](C& c) -> double& { return c.drive.motor.rs_ohm; }, between(common::kMinStatorResistance_ohm, common::kMaxStatorResistance_ohm), "ohm",
         "Nameplate phase-to-neutral resistance of the winding at motor.rs_reference_temp_C (a motor cable is "
         "motor.cable_resistance_ohm); with the cable, the temperature scale until a calibration replaces it.");
  s.real("motor.rs_reference_temp_C", [](C& c) -> double& { return c.drive.motor.rs_reference_temp_C; }, between(-50, 200), "C",
         "Temperature at which motor.rs_ohm holds (T0 of Eq. 1).");
  s.choice("motor.conductor", {{"copper", 0}, {"aluminium", 1}},
           [](const C& c) { return c.drive.thermal.conductor_inferred_zero_C == core::kAluminiumInferredZero_C ? 1 : 0; },
           [](C& c, int v) {
             c.drive.thermal.conductor_inferred_zero_C = v == 1 ? core::kAluminiumInferredZero_C : core::kCopperInferredZero_C;
           },
           "Winding conductor for Eq. 1 referred to any T0: resistance proportional to K + T, K = 234.5 C (copper: alpha "
           "3.93e-3 /C at 20 C, 3.85e-3 at 25 C) or 225 C (aluminium).");
  s.real("motor.cable_resistance_ohm", [](C& c) -> double& { return c.drive.thermal.cable_resistance_20C_ohm; },
         at_least(0, common::kMaxStatorResistance_ohm), "ohm",
         "A motor cable in series with the winding, per phase (half the line-to-line value) at 20 C, copper at the "
         "ambient sensor's temperature: part of every resistance the drive measures, which the drive adds to "
         "motor.rs_ohm (current loop, Rs0 before a calibration, plausibility window) and takes off before Eq. 1 and "
         "the copper loss. 0: none (a cable of 19 % of the total read 81 % of the winding's rise).");
  s.real("motor.ld_H", [](C& c) -> double& { return c.drive.motor.ld_H; }, between(common::kMinInductance_H, 1.0), "H", "d-axis inductance as commissioned.");
  s.real("motor.lq_H", [](C& c) -> double& { return c.drive.motor.lq_H; }, between(common::kMinInductance_H, 1.0), "H", "q-axis inductance as commissioned.");
  s.real("motor.lq_rated_H", [](C& c) -> double& { return c.drive.motor.lq_rated_H; }, at_least(0, 1.0), "H",
         "Secant q-axis inductance (psi_q / iq) at the rated current, from the motor's flux map or datasheet; 0: not known. "
         "On a saturating machine it gives the estimator the gap between the secant Lq that pairs at one load measure "
         "and the incremental Lq their fit needs (docs/estimator.md section 5.1). A map of several points "
         "(motor.lq_map_H) gives that gap between them better.");
  s.list("motor.lq_map_current_A", 0, core::LqMap::kMaxPoints, positive(1e5),
         [](const C& c) { return c.lq_map_current_A; }, [](C& c, const std::vector<double>& v) { c.lq_map_current_A = v; },
         "A", "q-axis currents (peak A, ascending, above 0: motor.lq_H is the map at 0 A) of the flux map's points in "
         "motor.lq_map_H, in place of motor.lq_rated_H. Let them reach past the loads the drive runs at.");
  s.list("motor.lq_map_H", 0, core::LqMap::kMaxPoints, between(common::kMinInductance_H, 1.0),
         [](const C& c) { return c.lq_map_H; }, [](C& c, const std::vector<double>& v) { c.lq_map_H = v; }, "H",
         "Secant q-axis inductance (psi_q / iq, not the incremental d psi_q / d iq) of the flux map at each of "
         "motor.lq_map_current_A, at id = 0, from the same map as motor.lq_H (its no-load value), non-increasing: the "
         "saturation curve's shape between the points, which one point at the rated current can only draw as a "
         "parabola (docs/estimator.md section 5.1).");
  s.real("motor.ke_V_s_per_rad", [](C& c) -> double& { return c.drive.motor.ke_V_s_per_rad; }, between(common::kMinEmfConstant_V_s_per_rad, 100.0), "V s/rad",
         "EMF constant, line-to-line RMS volts per mechanical rad/s (Table I: 1.19).");
  s.integer("motor.pole_pairs", [](C& c) -> int& { return c.drive.motor.pole_pairs; }, between(1, 64), "Pole pairs.");
  s.real("motor.continuous_current_A_rms", [](C& c) -> double& { return c.drive.motor.continuous_current_A_rms; }, between(common::kMinMotorCurrent_A, 10000), "A",
         "Rated (continuous) phase current, RMS (Table I Icont: 31.9 A). The injection, calibration and load-change defaults scale with "
         "its peak, the rated current I_rated = sqrt(2) times this.");
  s.real("motor.rated_speed_rad_s", [](C& c) -> double& { return c.drive.motor.rated_speed_rad_s; }, between(common::kMinMotorSpeed_rad_s, 100000), "rad/s",
         "Rated mechanical speed (Table I: 314 rad/s). control.speed_limit_rad_s, supervisor.overspeed_rad_s and "
         "supervisor.max_speed_rad_s default to 1.2, 1.5 and 3 times it.");
  s.real("motor.inertia_kg_m2", [](C& c) -> double& { return c.drive.motor.inertia_kg_m2; }, between(common::kMinInertia_kg_m2, common::kMaxInertia_kg_m2), "kg m^2",
         "Total inertia the speed loop is designed for.");
  // [sensors]
  s.integer("sensors.current_adc_bits", [](C& c) -> int& { return c.sensors.current_adc_bits; }, between(8, 16), "Phase-current ADC resolution.");
  s.real("sensors.current_range_A", [](C& c) -> double& { return c.sensors.current_range_A; }, positive(10000), "A",
         "Phase-current ADC full scale (+-).");
  s.real("sensors.current_gain_std_fraction", [](C& c) -> double& { return c.drive.injection.current_gain_std_fraction; },
         between(0.0, 0.2), "",
         "The phase-current sensors' gain error, one standard deviation per phase (0.01: a shunt and amplifier chain "
         "without a per-unit gain trim). A turning rotor averages their mismatch out of the injection pairs; at rest it "
         "does not, and an estimate made there carries sigma / sqrt(6) of Rs more in its error bar (docs/estimator.md "
         "section 5.7). 0: the sensors are matched.");
  s.integer("sensors.dc_bus_adc_bits", [](C& c) -> int& { return c.sensors.dc_bus_adc_bits; }, between(8, 16), "DC-bus ADC resolution.");
  s.real("sensors.dc_bus_full_scale_V", [](C& c) -> double& { return c.sensors.dc_bus_full_scale_V; }, positive(10000), "V",
         "DC-bus ADC full scale.");
  s.integer("sensors.encoder_bits", [](C& c) -> int& { return c.drive.angle.encoder_bits; }, between(8, 16),
            "Absolute encoder resolution (at most 16: SENSOR_SAMPLE's EncoderCount is 16 bits; a wider setting made every "
            "count the bus can carry look plausible, and the encoder-jump check never tripped).");
  s.real("sensors.encoder_count_centre", [](C& c) -> double& { return c.drive.angle.count_centre; }, between(0, 1), "counts",
         "Where the rotor lies on average inside the angles that read one count, from the count's lower edge: 0.5 for an "
         "encoder that truncates (reports the whole counts below the angle), 0 for one that rounds.");
  s.real("sensors.encoder_offset_rad", [](C& c) -> double& { return c.drive.angle.electrical_offset_rad; }, between(-7, 7), "rad",
         "Electrical angle at the lower edge of encoder count 0 (commissioned).");
  s.real("sensors.offset_calibration_s", [](C& c) -> double& { return c.sensors.offset_calibration_s; }, between(0, 10), "s",
         "Time at start-up, gates off, over which the current-ADC offsets are averaged (0: none).");
  s.optional_real("sensors.current_noise_A", [](C& c) -> std::optional<double>& { return c.sensors.current_noise_A; },
                  at_least(0, 100), "A", "measured",
                  "Standard deviation of one current sample's noise; the estimator corrects its sign pattern for it "
                  "(docs/estimator.md section 4). Absent: measured with the offsets at start-up (0 without them). 0: "
                  "no correction.");
  // [control]
  s.real("control.period_s", [](C& c) -> double& { return c.drive.period_s; }, between(2e-5, 1e-3), "s", "Current-loop period (the PWM period).");
  s.real("control.current_bandwidth_rad_s", [](C& c) -> double& { return c.drive.current.bandwidth_rad_s; }, positive(20000), "rad/s",
         "Current-loop bandwidth (Kp = wc L, Ki = wc Rs).");
  s.real("control.voltage_limit_fraction", [](C& c) -> double& { return c.drive.current.voltage_limit_fraction; }, between(0.5, 1.0), "",
         "Usable fraction of Vdc/sqrt(3).");
  s.real("control.speed_bandwidth_rad_s", [](C& c) -> double& { return c.drive.speed.bandwidth_rad_s; }, positive(2000), "rad/s",
         "Speed-loop bandwidth (Kp = motor.inertia_kg_m2 x it). Its proportional gain turns the encoder's rounding, read "
         "through the PLL's speed, into torque demand: J wc 2 wn (1 + wn T) q / sqrt(12) RMS, q = 2 pi / "
         "2^sensors.encoder_bits, wn = control.pll_bandwidth_rad_s, T = control.period_s. Above 5 % of the rated torque (Kt "
         "x the rated peak current) the loader warns, naming the bandwidth that keeps it there (docs/daemon.md, \"The speed "
         "loop and the encoder\").");
  s.integer("control.speed_decimation", [](C& c) -> int& { return c.drive.speed_decimation; }, between(1, 1000),
            "Speed loop every N current-loop periods.");
  s.optional_real("control.speed_limit_rad_s", [](C& c) -> std::optional<double>& { return c.relative.speed_limit_rad_s; },
                  at_least(0, 100000), "rad/s", "1.2 motor.rated_speed_rad_s",
                  "Shaft speed limit, either direction (0: none): speed mode clamps its set-point to it, torque mode bounds the "
                  "torque by G (limit - speed), G = motor.inertia_kg_m2 x min(5 control.speed_bandwidth_rad_s, "
                  "control.pll_bandwidth_rad_s / 2), so that an unloaded shaft settles there and one under a load T at "
                  "limit - T / G; DRIVE_STATUS.LimitSpeed says when it binds. Below supervisor.overspeed_rad_s.");
  s.optional_real("control.speed_ramp_rad_s2", [](C& c) -> std::optional<double>& { return c.relative.speed_ramp_rad_s2; },
                  at_least(0, 1e7), "rad/s^2", "a quarter of the current limit's torque / motor.inertia_kg_m2",
                  "Speed mode's set-point ramp (0: none, steps as commanded): the reference moves towards the set-point at "
                  "most this fast, with J x its slope as a torque feed-forward, so that a step neither winds the speed "
                  "loop's integral up nor overshoots the set-point (or the speed limit). The default, a quarter of "
                  "min(Kt derating.max_current_A, control.max_torque_Nm) / motor.inertia_kg_m2, leaves the rest of the "
                  "torque for the load and the loop, and keeps the PLL's speed lag (the ramp / its bandwidth) small.");
  s.boolean("control.field_weakening", [](C& c) -> bool& { return c.drive.field_weakening.enabled; },
            "Field weakening above the id = 0 speed: a negative d current, from a voltage loop, holds the current "
            "loop's command at control.field_weakening_voltage_fraction of its limit, so that the current stays under "
            "control and the shaft runs on past the speed where the EMF takes the bus (docs/daemon.md, \"Field "
            "weakening\"). Below that speed it asks nothing. Off by default: id = 0 control at every speed, as the "
            "reference benchmarks are measured.");
  s.optional_real("control.field_weakening_max_current_A",
                  [](C& c) -> std::optional<double>& { return c.relative.field_weakening_max_current_A; },
                  at_least(0, 100000), "A", "min(psi / motor.ld_H, derating.max_current_A)",
                  "Largest |id| field weakening asks (peak A); the q axis keeps sqrt(I^2 - id^2) of the current limit I. "
                  "Beyond the characteristic current psi / Ld (psi from motor.ke_V_s_per_rad) more -id weakens nothing. It "
                  "is also bounded by the magnets' derated current limit (derating.magnet_*).");
  s.real("control.field_weakening_bandwidth_rad_s", [](C& c) -> double& { return c.drive.field_weakening.bandwidth_rad_s; },
         positive(20000), "rad/s",
         "The field-weakening voltage loop's bandwidth (its gain is scheduled with the speed and motor.ld_H); keep it "
         "well below control.current_bandwidth_rad_s.");
  s.real("control.field_weakening_voltage_fraction",
         [](C& c) -> double& { return c.drive.field_weakening.voltage_fraction; }, between(0.5, 1.0), "",
         "Share of the current loop's voltage limit (control.voltage_limit_fraction x bus / sqrt(3)) at which field "
         "weakening holds the command: the rest is the current loop's reserve for its transients.");
  s.real("control.max_torque_Nm", [](C& c) -> double& { return c.drive.speed.max_torque_Nm; }, positive(10000), "Nm", "Torque demand limit.");
  s.real("control.pll_bandwidth_rad_s", [](C& c) -> double& { return c.drive.angle.pll_bandwidth_rad_s; }, positive(10000), "rad/s",
         "Speed observer (PLL) bandwidth.");
  s.real("control.nominal_dc_bus_V", [](C& c) -> double& { return c.nominal_dc_bus_V; }, between(common::kMinDcBus_V, 10000), "V",
         "Nominal DC-bus voltage (the inverter-error prior and Vx are referred to it).");
  s.real("control.dead_time_s", [](C& c) -> double& { return c.drive.dead_time.dead_time_s; }, between(0, 1e-5), "s",
         "Dead time the compensation assumes; the estimator's Vx follows the bus by it.");
  s.real("control.device_drop_V", [](C& c) -> double& { return c.drive.dead_time.device_drop_V; }, between(0, 10), "V",
         "Device forward drop the compensation assumes.");
  s.real("control.dead_time_band_A", [](C& c) -> double& { return c.drive.dead_time.current_band_A; }, between(0, 20), "A",
         "Below this |i| the compensation fades in linearly (PWM ripple).");
  // [injection]
  auto& inj = s;
  inj.choice("injection.method",
             {{"fixed-magnitude", static_cast<int>(InjectionMethod::kFixedMagnitude)},
              {"fixed-angle", static_cast<int>(InjectionMethod::kFixedAngle)},
              {"dc", static_cast<int>(InjectionMethod::kDc)},
              {"none", static_cast<int>(InjectionMethod::kNone)}},
             [](const C& c) { return static_cast<int>(c.drive.injection.method); },
             [](C& c, int v) { c.drive.injection.method = static_cast<InjectionMethod>(v); },
             "Injection profile: fixed-magnitude (Eqs. 16-21), fixed-angle (Eqs. 11-15), dc (Eqs. 4-9, baseline), none.");
  inj.choice("injection.separation",
             {{"bipolar", static_cast<int>(Separation::kBipolar)}, {"unipolar", static_cast<int>(Separation::kUnipolar)}},
             [](const C& c) { return static_cast<int>(c.drive.injection.separation); },
             [](C& c, int v) { c.drive.injection.separation = static_cast<Separation>(v); },
             "Separation of the injected voltage: bipolar (Eqs. 39-44) or unipolar (Eqs. 33-38).");
  inj.optional_real("injection.F_A", [](C& c) -> std::optional<double>& { return c.relative.injection_f_A; }, positive(1000), "A",
                    "0.776 I_rated", "Injection magnitude F (phase peak) at level 1 (Table I: 35 A).");
  inj.optional_real("injection.F_min_A", [](C& c) -> std::optional<double>& { return c.relative.injection_f_min_A; },
                    positive(1000), "A", "0.111 I_rated",
                    "Below this, after the current and voltage budget, a pair is skipped (Table I: 5 A).");
  inj.list("injection.levels", 1, core::InjectionConfig::kMaxLevels, between(0.05, 1.0),
           [](const C& c) {
             const auto& i = c.drive.injection;
             return std::vector<double>(i.levels.begin(), i.levels.begin() + i.level_count);
           },
           [](C& c, const std::vector<double>& v) {
             auto& i = c.drive.injection;
             i.levels.fill(0.0);
             std::copy(v.begin(), v.end(), i.levels.begin());
             i.level_count = static_cast<int>(v.size());
           },
           "", "Multipliers of F, one pair each per event; two or more separate Rs from the inverter's voltage error.");
  inj.real("injection.interval_s", [](C& c) -> double& { return c.drive.injection.interval_s; }, positive(1e6), "s",
           "Time between injection events.");
  inj.real("injection.retry_s", [](C& c) -> double& { return c.drive.injection.retry_s; }, positive(1e6), "s",
           "Retry delay after an event that yielded nothing. One whose last level was refused for its budget "
           "(current, voltage or torque: rejected_current_limit, rejected_voltage_headroom, skipped_torque_disturbance) "
           "with no pair accepted is followed by the next this long after it, not a whole interval_s after its start; "
           "one aborted during a pair, no sooner than this (nor than its interval), except after speed_lost, where it "
           "starts again once the shaft rests (injection.record_time_s); any other, at its interval. A request (a "
           "calibration's, an operator's) waits it after any of them.");
  inj.real("injection.retry_jitter", [](C& c) -> double& { return c.drive.injection.retry_jitter; }, between(0.0, 2.0), "",
           "From the second refused event in a row, the delay to the next is scaled by 1 + retry_jitter v, v uniform in [0, 1): no lock onto a duty whose period divides it.");
  inj.real("injection.first_event_s", [](C& c) -> double& { return c.drive.injection.first_event_s; }, at_least(0, 1e7), "s",
           "Time of the first event after start.");
  inj.choice("injection.window",
             {{"blackman", static_cast<int>(WindowKind::kBlackman)}, {"modified", static_cast<int>(WindowKind::kModifiedBlackman)}},
             [](const C& c) { return static_cast<int>(c.drive.injection.window); },
             [](C& c, int v) { c.drive.injection.window = static_cast<WindowKind>(v); },
             "Window of the pulse edges: blackman (Eq. 23) or modified (Eq. 24).");
  inj.optional_real("injection.Tw_s", [](C& c) -> std::optional<double>& { return c.relative.tw_s; }, positive(core::kMaxWindowPeriod_s), "s",
                    "4 ms, or k Ld F / (Vdc / sqrt(3) / 2) where longer",
                    "Window period of each edge. The default is the paper's 4 ms, lengthened where an edge of the larger of "
                    "injection.F_A and calibration.F_A through motor.ld_H would take more than half the phase voltage limit "
                    "control.nominal_dc_bus_V / sqrt(3) (Eq. 29's inductive term k Ld F / Tw, k = 2.04 for the modified "
                    "Blackman window, 1.81 for Blackman; docs/estimator.md section 2, \"The window's period\").");
  inj.real("injection.settle_s", [](C& c) -> double& { return c.drive.injection.settle_s; }, at_least(0, 1.0), "s",
           "Wait after an edge before recording.");
  inj.real("injection.record_arc_rad", [](C& c) -> double& { return c.drive.injection.record_arc_rad; }, positive(1000), "rad",
           "Shortest angle-based recording (electrical; rounded up to whole turns).");
  inj.real("injection.record_min_time_s", [](C& c) -> double& { return c.drive.injection.record_min_time_s; }, at_least(0, 10), "s",
           "Shortest angle-based recording in time (whole turns).");
  inj.real("injection.field_weakening_record_min_time_s",
           [](C& c) -> double& { return c.drive.injection.field_weakening_record_min_time_s; }, at_least(0, 10), "s",
           "Field-weakening pairs: shortest recording in time (whole turns; never below record_min_time_s). Their "
           "cross-coupling term turns current-sensor noise into d-axis voltage at w Lq: longer recordings average it.");
  inj.real("injection.record_time_s", [](C& c) -> double& { return c.drive.injection.record_time_s; }, positive(10), "s",
           "Time-based recording length (standstill, low speed).");
  inj.boolean("injection.mechanical_harmonics", [](C& c) -> bool& { return c.drive.injection.mechanical_harmonics; },
              "dTheta a multiple of 2 pi p (mechanical harmonics) instead of 2 pi.");
  inj.real("injection.mechanical_harmonics_min_speed_rad_s",
           [](C& c) -> double& { return c.drive.injection.mechanical_harmonics_min_speed_rad_s; }, at_least(0, 10000),
           "rad/s", "... at mechanical speeds from this on; slower, dTheta is a multiple of 2 pi (a pair would span a slow mechanical turn).");
  inj.real("injection.min_speed_for_angle_rad_s", [](C& c) -> double& { return c.drive.injection.min_speed_for_angle_rad_s; },
           at_least(0, 10000), "rad/s", "Electrical speed below which recordings are time-based.");
  inj.integer("injection.unipolar_polarity", [](C& c) -> int& { return c.drive.injection.unipolar_polarity; }, between(-1, 1),
              "Sign of F for unipolar separation (-1 lowers the voltage).");
  inj.boolean("injection.field_weakening_pairs", [](C& c) -> bool& { return c.drive.injection.field_weakening_pairs; },
              "At the voltage limit, record at two negative levels (-lo, -F) instead of skipping the pair.");
  inj.real("injection.field_weakening_low_fraction",
           [](C& c) -> double& { return c.drive.injection.field_weakening_low_fraction; }, between(0.05, 0.9), "",
           "Field-weakening pairs: least lower level, as a fraction of the upper.");
  inj.real("injection.field_weakening_pattern_error",
           [](C& c) -> double& { return c.drive.injection.field_weakening_pattern_error; }, between(0, 1), "",
           "The bridge's sign pattern's error as a fraction of its term: in the Rs of field-weakening and unipolar "
           "pairs (one-sided: the error's part even in the pulse does not cancel), and in every event's magnet reading "
           "(a shared error in the band).");
  inj.real("injection.field_weakening_rs_error",
           [](C& c) -> double& { return c.drive.injection.field_weakening_rs_error; }, between(0, 1), "",
           "Field-weakening pairs: their error apart from the bridge, as a fraction of Rs (a shared error in the band).");
  inj.real("injection.theta_f_rad", [](C& c) -> double& { return c.drive.injection.theta_f_rad; }, between(-7, 7), "rad",
           "Angle of the fixed-angle / DC injection vector (electrical).");
  inj.real("injection.beta", [](C& c) -> double& { return c.drive.injection.beta; }, between(0, 1), "", "Regulation factor (Eq. 12).");
  inj.real("injection.injection_arc_rad", [](C& c) -> double& { return c.drive.injection.injection_arc_rad; }, positive(100), "rad",
           "Fixed-angle: flat part of the arc (theta_i).");
  inj.real("injection.window_arc_rad", [](C& c) -> double& { return c.drive.injection.window_arc_rad; }, positive(100), "rad",
           "Fixed-angle: each window edge (theta_w), widened to Tw_s at speed.");
  inj.real("injection.dc_revolutions", [](C& c) -> double& { return c.drive.injection.dc_revolutions; }, positive(100), "",
           "DC injection: recording length in electrical turns.");
  inj.optional_real("injection.headroom_margin_V", [](C& c) -> std::optional<double>& { return c.relative.headroom_margin_V; },
                    at_least(0, 1000), "V", "0.0231 control.nominal_dc_bus_V",
                    "Voltage kept free of the limit when budgeting F: the dead-time compensation, the bus's ripple and sag, the current loop's transients, all of which scale with the bus (Table I: 15 V at 650 V).");
  inj.real("injection.max_torque_disturbance_Nm", [](C& c) -> double& { return c.drive.injection.max_torque_disturbance_Nm; },
           at_least(0, 10000), "Nm", "Budget for the reluctance torque of an injection on a salient machine (0: none).");
  inj.boolean("injection.torque_neutral", [](C& c) -> bool& { return c.drive.injection.torque_neutral; },
              "With a torque budget: each fixed-magnitude pulse moves iq so that iq (psi + (Ld - Lq) id) holds the "
              "motoring torque (commissioned Ld, learned Lq); the budget still bounds F by the uncompensated torque. "
              "false: the pulses are on the d-axis alone and the speed loop answers their torque.");
  inj.real("injection.max_speed_change_fraction", [](C& c) -> double& { return c.drive.injection.max_speed_change_fraction; },
           between(0, 1), "", "Reject a pair whose recordings differ in speed by more than this fraction (not a listening pair)...");
  inj.optional_real("injection.max_speed_change_rad_s", [](C& c) -> std::optional<double>& { return c.relative.max_speed_change_rad_s; },
                    at_least(0, 1e6), "rad/s", "0.124 Rs/Lq",
                    "... or by more than this (electrical), whichever is larger (Table I: 3 rad/s).");
  inj.optional_real("injection.max_load_change_A", [](C& c) -> std::optional<double>& { return c.relative.max_load_change_A; },
                    at_least(0, 1e6), "A", "0.0332 I_rated",
                    "Reject a pair whose recordings differ in motoring iq by more than this, beyond the speed loop's answer to the pulses' reluctance torque (Table I: 1.5 A).");
  inj.real("injection.max_residual_V", [](C& c) -> double& { return c.drive.injection.max_residual_V; }, positive(1000), "V",
           "Reject a pair whose fit residual (RMS) exceeds this.");
  inj.real("injection.min_condition", [](C& c) -> double& { return c.drive.injection.min_condition; }, between(0, 1), "",
           "Reject a fit whose regressors are more collinear than this (reciprocal condition).");
  inj.optional_real("injection.rs_min_ohm", [](C& c) -> std::optional<double>& { return c.relative.rs_min_ohm; }, positive(100), "ohm",
                    "0.677 motor.rs_ohm (+ the cable)", "Plausibility window of a resistance estimate, lower end (Table I: 0.09 ohm, about -57 C).");
  inj.optional_real("injection.rs_max_ohm", [](C& c) -> std::optional<double>& { return c.relative.rs_max_ohm; }, positive(100), "ohm",
                    "2.03 motor.rs_ohm (+ the cable)", "Plausibility window, upper end (Table I: 0.27 ohm, about 287 C).");
  inj.boolean("injection.fit_dead_time", [](C& c) -> bool& { return c.drive.injection.fit_dead_time; },
              "Model the inverter's uncompensated voltage Vx (learned across events).");
  inj.boolean("injection.fit_inductance", [](C& c) -> bool& { return c.drive.injection.fit_inductance; },
              "Fit the inductive voltage Ld d(dId/dt) within a recording.");
  inj.real("injection.vx_initial_V", [](C& c) -> double& { return c.drive.injection.vx_initial_V; }, between(-50, 50), "V",
           "The bridge's dead-time + drop voltage per phase before the first event (default: what the compensation assumes at control.nominal_dc_bus_V).");
  inj.real("injection.vx_initial_std_V", [](C& c) -> double& { return c.drive.injection.vx_initial_std_V; }, positive(100), "V",
           "Its uncertainty.");
  inj.real("injection.vx_drift_fraction", [](C& c) -> double& { return c.drive.injection.vx_drift_fraction; }, at_least(0, 1), "",
           "How far the estimator's Vx (at control.nominal_dc_bus_V; learned, or the prior before) may wander between two events, "
           "as a share of itself: one standard deviation per event, so more per minute at a shorter injection.interval_s. "
           "The default, the reference plant's 5 mV at its 7.5 V bridge, was not measured on a bridge; 0 with "
           "vx_drift_std_V 0 holds Vx fixed between learning events (docs/estimator.md section 4).");
  inj.real("injection.vx_drift_std_V", [](C& c) -> double& { return c.drive.injection.vx_drift_std_V; }, at_least(0, 100), "V",
           "An absolute part of that drift per event, in quadrature with the share.");
  inj.optional_real("injection.vx_bus_slope_std_V_per_V", [](C& c) -> std::optional<double>& { return c.relative.vx_bus_slope_std; },
                    at_least(0, 1), "V/V", "0.2 control.dead_time_s x PWM frequency",
                    "Uncertainty of the bridge's dead-time share of the bus (V of Vx per V of bus) beyond what control.dead_time_s "
                    "assumes: learned from events that learn Vx at different buses, and until then the held Vx's uncertainty "
                    "grows with the bus's distance from control.nominal_dc_bus_V (docs/estimator.md section 4). 0: not modelled.");
  inj.optional_real("injection.vx_learning_max_speed_rad_s",
                    [](C& c) -> std::optional<double>& { return c.relative.vx_learning_max_speed_rad_s; }, at_least(0, 1e5),
                    "rad/s", "max(600, 0.06 / control.period_s)",
                    "Learn Vx only from events slower than this (electrical): 600 rad/s, or faster at control rates above "
                    "10 kHz as long as the rotor turns at most 0.06 rad in a period, 105 periods an electrical turn "
                    "(docs/estimator.md section 4, \"How fast an event may learn Vx\"); a calibration faster than this "
                    "cannot learn it and is refused (calibration.max_rs0_std_fraction).");
  inj.real("injection.vx_learning_max_iq_fraction", [](C& c) -> double& { return c.drive.injection.vx_learning_max_iq_fraction; },
           at_least(0, 100), "",
           "... and whose motoring |iq| stays below this fraction of the event's smallest F (its pairs reverse the current).");
  inj.real("injection.vx_min_identifiability", [](C& c) -> double& { return c.drive.injection.vx_min_identifiability; },
           between(0, 1), "", "... and whose levels separate Rs from Vx at least this well (1 - rho^2 of the means fit, weighted; below "
           "injection.min_speed_for_angle_rad_s / 10, of the levels' design, unweighted).");
  inj.boolean("injection.learn_lq", [](C& c) -> bool& { return c.drive.injection.learn_lq; },
              "Learn the q-axis inductance from the pairs' d-axis means (the Eq. 37 correction needs the true Lq).");
  inj.real("injection.lq_initial_std_fraction", [](C& c) -> double& { return c.drive.injection.lq_initial_std_fraction; },
           positive(1), "", "Uncertainty of the commissioned motor.lq_H, as a fraction of it.");
  inj.real("injection.lq_drift_fraction", [](C& c) -> double& { return c.drive.injection.lq_drift_fraction; }, at_least(0, 1), "",
           "How far the learned Lq may wander between pairs, as a fraction of motor.lq_H.");
  inj.real("injection.lq_saturation_std_fraction",
           [](C& c) -> double& { return c.drive.injection.lq_saturation_std_fraction; }, between(0, 1), "",
           "Prior of the learned Lq's saturation (secant lost at the current limit), as a fraction of Lq, around 0; also the "
           "uncertainty of motor.lq_rated_H's gap until pairs at two loads resolve the curve, and the prior of its bend (a "
           "further loss in s^2) once pairs at three loads have taught it. 0: one Lq at every load.");
  inj.real("injection.lq_learning_min_voltage_V", [](C& c) -> double& { return c.drive.injection.lq_learning_min_voltage_V; },
           at_least(0, 1000), "V", "Learn Lq only from pairs whose Lq <w iq> is at least this.");
  inj.boolean("injection.lq_listening", [](C& c) -> bool& { return c.drive.injection.lq_listening; },
              "Where the torque budget refuses every pulse and no load near it has taught Lq's curve, record a pair with "
              "no pulse (a listening pair): its d-axis means give the secant Lq at that load (docs/estimator.md section 5.1).");
  inj.real("injection.lq_angle_std_rad", [](C& c) -> double& { return c.drive.injection.lq_angle_std_rad; },
           between(0, 0.1), "rad",
           "Rotor-angle error (electrical) the Lq learner allows for until a rotor-angle check measures it (the check's "
           "result replaces it): its EMF share psi delta on the d axis is learned with Lq's curve, not taken for Lq. "
           "0: none until a check (pairs at one load cannot tell it from an Lq error). Not on a salient machine.");
  // [estimator]
  s.choice("estimator.kind",
           {{"injection", static_cast<int>(EstimatorKind::kInjection)},
            {"no-injection", static_cast<int>(EstimatorKind::kNoInjection)},
            {"none", static_cast<int>(EstimatorKind::kNone)}},
           [](const C& c) { return static_cast<int>(c.drive.estimator); },
           [](C& c, int v) { c.drive.estimator = static_cast<EstimatorKind>(v); },
           "Resistance source: injection (the scheduler), no-injection (voltage-equation baseline), none (thermal model only).");
  s.real("estimator.baseline_memory_s", [](C& c) -> double& { return c.drive.baseline.memory_s; }, positive(1e6), "s",
         "No-injection baseline: RLS forgetting horizon.");
  s.real("estimator.baseline_publish_s", [](C& c) -> double& { return c.drive.baseline_publish_s; }, positive(1e6), "s",
         "No-injection baseline: how often its estimate is fused.");
  // [thermal]
  s.real("thermal.winding_capacity_J_K", [](C& c) -> double& { return c.drive.thermal.winding_capacity_J_K; }, between(common::kMinHeatCapacity_J_K, 1e9), "J/K",
         "Controller's model: winding heat capacity.");
  s.real("thermal.housing_capacity_J_K", [](C& c) -> double& { return c.drive.thermal.housing_capacity_J_K; }, between(common::kMinHeatCapacity_J_K, 1e9), "J/K",
         "Controller's model: stator/housing heat capacity.");
  s.real("thermal.winding_to_housing_K_W", [](C& c) -> double& { return c.drive.thermal.winding_to_housing_K_W; }, between(common::kMinThermalResistance_K_W, 100), "K/W",
         "Controller's model: winding to housing.");
  s.real("thermal.housing_to_ambient_K_W", [](C& c) -> double& { return c.drive.thermal.housing_to_ambient_K_W; }, between(common::kMinThermalResistance_K_W, 100), "K/W",
         "Controller's model: housing to ambient (with a shaft fan: at thermal.fan_speed_rad_s).");
  s.real("thermal.fan_speed_rad_s", [](C& c) -> double& { return c.drive.thermal.fan_speed_rad_s; }, between(0, 1e4),
         "rad/s",
         "A shaft-mounted fan (a self-ventilated machine, IC411): the mechanical speed at which "
         "thermal.housing_to_ambient_K_W holds (the data sheet's rated speed); the path's conductance scales as "
         "fan_standstill_share + (1 - fan_standstill_share) (|speed| / fan_speed_rad_s)^fan_exponent. 0: no shaft fan "
         "(separately ventilated, water-jacketed or non-ventilated: the path does not depend on the speed).");
  s.real("thermal.fan_standstill_share", [](C& c) -> double& { return c.drive.thermal.fan_standstill_share; },
         between(0.01, 1), "",
         "With a shaft fan: the share of the housing's cooling left at standstill (natural convection; from a data "
         "sheet's torque at zero speed over the rated torque, k = (T0 / Tn)^2: share = Rha / ((Rwh + Rha) / k - Rwh), "
         "less than k itself).");
  s.real("thermal.fan_exponent", [](C& c) -> double& { return c.drive.thermal.fan_exponent; }, between(0.1, 2), "",
         "With a shaft fan: how its share of the cooling grows with the speed (0.8: forced convection, the air flow in "
         "proportion to the speed).");
  s.real("thermal.iron_loss_k1_W_s_rad", [](C& c) -> double& { return c.drive.thermal.iron_loss_k1_W_s_rad; }, at_least(0, 1e4), "W s/rad",
         "Iron loss per mechanical rad/s.");
  s.real("thermal.iron_loss_k2_W_s2_rad2", [](C& c) -> double& { return c.drive.thermal.iron_loss_k2_W_s2_rad2; }, at_least(0, 1e3), "W s^2/rad^2",
         "Iron loss per (mechanical rad/s)^2.");
  s.real("thermal.acceleration", [](C& c) -> double& { return c.drive.thermal.time_scale; }, positive(1e6), "",
         "Thermal time runs this many times faster than controller time (1 on a real machine; the plant's acceleration in "
         "tests). Times thermal.update_s, at most half the thermal model's fastest time constant (the filter's step).");
  s.boolean("thermal.calibration_real_time", [](C& c) -> bool& { return c.calibration_real_time; },
            "With an acceleration other than 1 (a test), run a calibration at real thermal time, as on a machine (pmsm-plant follows THERMAL_ESTIMATE.Calibrating).");
  s.real("thermal.update_s", [](C& c) -> double& { return c.drive.thermal_update_s; }, positive(10), "s", "Thermal filter period.");
  s.real("thermal.initial_std_C", [](C& c) -> double& { return c.drive.thermal.initial_std_C; }, positive(1000), "C", "Initial uncertainty.");
  s.real("thermal.winding_process_std_C_per_sqrt_s", [](C& c) -> double& { return c.drive.thermal.winding_process_std_C_per_sqrt_s; },
         at_least(0, 100), "C/sqrt(s)", "Process noise of the winding node (per thermal second).");
  s.real("thermal.housing_process_std_C_per_sqrt_s", [](C& c) -> double& { return c.drive.thermal.housing_process_std_C_per_sqrt_s; },
         at_least(0, 100), "C/sqrt(s)", "Process noise of the housing node.");
  s.optional_real("thermal.loss_error_process_std_W_per_sqrt_s",
                  [](C& c) -> std::optional<double>& { return c.relative.loss_error_process_std_W_per_sqrt_s; }, at_least(0, 1e6),
                  "W/sqrt(s)", "0.0625 K/sqrt(s) / thermal.housing_to_ambient_K_W",
                  "Random walk of the missing loss on the housing node (per thermal second; Table I: 0.5 W/sqrt(s)), in "
                  "proportion to the cooling path's conductance.");
  s.optional_real("thermal.initial_loss_error_std_W",
                  [](C& c) -> std::optional<double>& { return c.relative.initial_loss_error_std_W; }, at_least(0, 1e7), "W",
                  "6.25 K / thermal.housing_to_ambient_K_W",
                  "Initial uncertainty of the missing loss on the housing node (iron, friction, rotor, the cooling path's "
                  "error at one temperature; Table I: 50 W), in proportion to the cooling path's conductance.");
  s.real("thermal.loss_scale_process_std_per_sqrt_s", [](C& c) -> double& { return c.drive.thermal.loss_scale_process_std_per_sqrt_s; },
         at_least(0, 1), "1/sqrt(s)", "Random walk of the copper-loss model's relative error (per thermal second).");
  s.real("thermal.initial_loss_scale_std", [](C& c) -> double& { return c.drive.thermal.initial_loss_scale_std; }, at_least(0, 10), "",
         "Initial uncertainty of the copper-loss model's relative error (0.2: the model within about 20 %).");
  s.real("thermal.initial_cooling_scale_std", [](C& c) -> double& { return c.drive.thermal.initial_cooling_scale_std; },
         between(0, 1), "",
         "Initial uncertainty of the cooling path's relative error g, which the filter learns (the housing sheds 1 + g times "
         "what thermal.housing_to_ambient_K_W passes; 0.25: a resistance to the ambient known within about a quarter; 0: g "
         "not learned).");
  s.real("thermal.cooling_scale_process_std_per_sqrt_s",
         [](C& c) -> double& { return c.drive.thermal.cooling_scale_process_std_per_sqrt_s; }, at_least(0, 1), "1/sqrt(s)",
         "Random walk of the cooling path's relative error (per thermal second; 0: a machine's cooling path holds).");
  s.real("thermal.model_error_fraction", [](C& c) -> double& { return c.drive.thermal.model_error_fraction; }, between(0, 1), "",
         "An extra, unlearned share of the winding's uncertainty between measurements: this fraction of the temperature change "
         "the model predicted since the last fused measurement (0, the default since 2026-11-28, 0.25 before: the band grows "
         "through the loss-error states' priors, which the measurements teach, and the process noise; docs/estimator.md section 7).");
  s.real("thermal.downtime_error_fraction", [](C& c) -> double& { return c.drive.thermal.downtime_error_fraction; }, between(0, 1), "",
         "A motor at rest (the drive disabled) or a stored thermal state cooled through the downtime: the winding's uncertainty "
         "grows by this fraction of the change the model predicts meanwhile (the cooling path's relative error; no loss runs to "
         "teach the loss states; on top of what the learned cooling error's variance adds, a conservative overlap).");
  s.real("thermal.measurement_floor_std_C", [](C& c) -> double& { return c.drive.thermal.measurement_floor_std_C; }, at_least(0, 1000), "C",
         "Added in quadrature to every measurement's own error.");
  s.real("thermal.gate_sigma", [](C& c) -> double& { return c.drive.thermal.gate_sigma; }, positive(1000), "",
         "A measurement further than this many sigma from the prediction is gated out.");
  s.real("thermal.huber_sigma", [](C& c) -> double& { return c.drive.thermal.huber_sigma; }, between(1, 1000), "",
         "A measurement further than this many sigma from the prediction (and inside the gate) is fused with its variance "
         "scaled by how far beyond it lies (Huber's weight): it moves the estimate as far as one at this distance would, no "
         "further. At or above thermal.gate_sigma it is off.");
  // [calibration]
  s.real("calibration.rs0_ohm", [](C& c) -> double& { return c.drive.calibration.rs0_ohm; }, between(common::kMinStatorResistance_ohm, common::kMaxStatorResistance_ohm), "ohm",
         "Rs0 of a stored calibration: what the drive measures at T0, a motor cable's share included (defaults to "
         "motor.rs_ohm plus motor.cable_resistance_ohm at motor.rs_reference_temp_C).");
  s.real("calibration.t0_C", [](C& c) -> double& { return c.drive.calibration.t0_C; }, between(-50, 200), "C", "T0 of that calibration.");
  s.real("calibration.t0_std_C", [](C& c) -> double& { return c.drive.thermal.reference_std_C; }, between(0, 20), "C",
         "The standard uncertainty of the temperature a calibration refers Rs0 to: the ambient / coolant sensor's "
         "accuracy (an NTC of +-2 C at two sigma: 1), or that of an operator's reading. Every estimate shares its error "
         "through Eq. 1, (234.5 + T) / (234.5 + T0) times it for copper, so it widens the band, and the derating's "
         "T + k sigma, once a calibration run's Rs0 is in use (docs/estimator.md section 6). 0: the sensor taken as exact.");
  s.real("calibration.rs0_std_fraction", [](C& c) -> double& { return c.drive.calibration.rs0_std_fraction; }, between(0, 0.5), "",
         "The relative standard uncertainty of Rs0 while no calibration run of this drive has measured it (a data "
         "sheet's +-10 % tolerance is about 0.05; a four-wire measurement at a known temperature about 0.005): every "
         "estimate shares its error, so it widens the band, and the derating's T + k sigma, by (234.5 + T) times it for "
         "copper (times Rs0 over the winding's share with a motor cable), until a calibration replaces it (docs/estimator.md section 6). Default 0.05 for the nameplate's "
         "motor.rs_ohm, 0 where calibration.rs0_ohm is given (a stored calibration's).");
  s.real("calibration.ke0_V_s_per_rad", [](C& c) -> double& { return c.drive.calibration.ke0_V_s_per_rad; }, at_least(0, 100), "V s/rad",
         "Eq. 3's Ke at T0 (0: not calibrated; no magnet temperature): phase-peak volts per mechanical rad/s, psi p, "
         "which is motor.ke_V_s_per_rad (line-to-line RMS) x sqrt(2/3) for the same machine.");
  s.real("calibration.dead_time_band_A", [](C& c) -> double& { return c.drive.calibration.dead_time_band_A; }, at_least(0, 1000),
         "A", "The bridge's zero-current band a calibration's sweep measured (0: not measured, control.dead_time_band_A holds).");
  s.real("calibration.vx_V", [](C& c) -> double& { return c.drive.calibration.vx_V; }, between(-50, 50), "V",
         "The bridge's voltage error (dead time and drop per phase) the calibration's events learned with Rs0; with "
         "calibration.vx_std_V it replaces injection.vx_initial_V as the estimator's prior (docs/estimator.md section 4).");
  s.real("calibration.vx_std_V", [](C& c) -> double& { return c.drive.calibration.vx_std_V; }, at_least(0, 100), "V",
         "Its standard error (0: not learned; injection.vx_initial_V and vx_initial_std_V hold), at calibration.vx_bus_V.");
  s.real("calibration.vx_bus_V", [](C& c) -> double& { return c.drive.calibration.vx_bus_V; }, at_least(0, 10000), "V",
         "The bus the calibration learned calibration.vx_V on (0: control.nominal_dc_bus_V): calibration.vx_std_V is its error "
         "there, and away from it the bus slope's uncertainty (injection.vx_bus_slope_std_V_per_V) adds.");
  s.optional_real("calibration.angle_correction_rad", [](C& c) -> std::optional<double>& { return c.angle_correction_rad; },
                  between(-1, 1), "rad", "none measured",
                  "The correction of sensors.encoder_offset_rad a calibration's rotor-angle check measured (electrical, "
                  "added to the controller's angle).");
  s.string("calibration.file", [](C& c) -> std::string& { return c.calibration_file; },
           "Where the calibration is kept: read at start-up in place of the calibration keys above, replaced atomically when a "
           "calibration run completes (relative to this file; empty: none).");
  s.string("thermal.state_file", [](C& c) -> std::string& { return c.thermal_state_file; },
           "Where the daemon keeps the thermal filter's state across a restart (written every 10 s and at stop, restored "
           "cooled through the downtime; relative to this file; empty: none, the filter starts from the ambient sensor). "
           "One file per axis: it records the axis that wrote it (can.interface, can.node), and a daemon of another "
           "axis does not take it.");
  s.integer("calibration.events", [](C& c) -> int& { return c.drive.calibration_events; }, between(1, 100),
            "Injection events averaged by a calibration run.");
  s.real("calibration.timeout_s", [](C& c) -> double& { return c.drive.calibration_timeout_s; }, between(1, 3600), "s",
         "A calibration run without enough published events by then gives up; the calibration in use stays "
         "(calibration.min_events).");
  s.integer("calibration.min_events", [](C& c) -> int& { return c.drive.calibration_min_events; }, between(0, 100),
            "A calibration run that has published at least this many events by calibration.timeout_s (a load came "
            "before its end) completes with them: their Rs0, with its larger standard error, refused as a whole run's "
            "would be. 0, or calibration.events or more: it gives up instead.");
  s.real("calibration.max_winding_rise_C", [](C& c) -> double& { return c.drive.calibration_max_winding_rise_C; },
         between(0, 200), "C",
         "A calibration on the ambient sensor's temperature is refused while the thermal filter holds the winding more "
         "than this above the ambient it runs on (the drive's own losses since it started, a stored warm state): Rs0 "
         "would be referred to a temperature the winding is not at. On the nameplate's Rs0 (no calibration yet) the model "
         "alone is the reference instead: a calibration starts at the ambient plus the model's rise, half the filter's "
         "rise beyond it (the nameplate's error or a warm winding: no measurement on the nameplate tells them apart) "
         "joins T0's uncertainty, and beyond the limit, by either rise, it is refused only where that uncertainty is too "
         "large to beat the nameplate (calibration.model_rise_std_fraction; docs/estimator.md section 6). 0: no check (that reference still counts the rise). An operator's temperature "
         "(CALIBRATION_REQUEST) is checked only against a resistance measurement of the last 60 s: refused more than "
         "4 sigma + this from it.");
  s.real("calibration.model_rise_std_fraction",
         [](C& c) -> double& { return c.drive.calibration_model_rise_std_fraction; }, positive(1.0), "",
         "On the nameplate's Rs0 (no calibration yet) a calibration on the ambient sensor starts at the ambient plus "
         "the thermal model's rise by the drive's own losses; that rise is known to this fraction of itself (the "
         "commissioned winding capacity and copper loss). It is T0's uncertainty, kept with the calibration and in the "
         "band. Above calibration.max_winding_rise_C such a calibration is taken while this uncertainty stays below half "
         "the nameplate's (calibration.rs0_std_fraction, in kelvin), and refused beyond; not after a restored thermal "
         "state, whose rise was measured through the same nameplate (docs/estimator.md section 6).");
  s.real("calibration.max_rs0_std_fraction", [](C& c) -> double& { return c.drive.calibration_max_rs0_std_fraction; },
         between(1e-4, 1.0), "",
         "A calibration run whose Rs0 standard error exceeds this fraction of Rs0 is refused and the calibration in use "
         "stays (2 % of Rs0 is about 5 C at 25 C); it happens where the events cannot learn the bridge's voltage, e.g. "
         "turning faster than injection.vx_learning_max_speed_rad_s or under load.");
  s.optional_real("calibration.F_A", [](C& c) -> std::optional<double>& { return c.relative.calibration_f_A; }, positive(1000), "A",
                  "1.11 I_rated",
                  "Injection magnitude of the calibration procedure (fixed-magnitude bipolar, levels 1 and 0.4), at no load (Table I: 50 A).");
  s.boolean("calibration.inverter_sweep", [](C& c) -> bool& { return c.drive.inverter_sweep.enabled; },
            "Measure the bridge's voltage error (Vx and its zero-current band) with a d-axis current sweep before the "
            "calibration's events: 12 levels up to half calibration.F_A, about 0.5 s (docs/estimator.md section 4.1).");
  s.boolean("calibration.angle_check", [](C& c) -> bool& { return c.drive.angle_check.enabled; },
            "Check the rotor angle's offset before the sweep: d-axis levels of +-half calibration.F_A held at the "
            "calibration's steady speed, the q current the speed loop needs at each; corrects sensors.encoder_offset_rad "
            "by up to calibration.angle_check_max_offset_rad (docs/estimator.md section 6.1).");
  s.real("calibration.angle_check_max_offset_rad", [](C& c) -> double& { return c.drive.angle_check.max_offset_rad; },
         positive(1.0), "rad",
         "A rotor angle found further off than this (electrical; the measured offset, or the correction it would make "
         "in all) is a commissioning error to fix, not to correct: the calibration is refused (reason angle_offset).");
  s.real("calibration.angle_check_min_correction_rad", [](C& c) -> double& { return c.drive.angle_check.min_correction_rad; },
         between(0, 1.0), "rad",
         "A rotor-angle offset the check finds below this, or inside three times its error bar, is not corrected (electrical): the check's own error (the speed "
         "loop's settling, the commissioned saliency times the no-load current) is of that order.");
  s.real("calibration.inverter_sweep_level_s", [](C& c) -> double& { return c.drive.inverter_sweep.average_s; },
         between(0.005, 1.0), "s", "Averaging time per sweep level (extended to whole electrical turns when turning).");
  s.real("calibration.magnet_temp_coefficient_per_C", [](C& c) -> double& { return c.drive.magnet_coefficient_per_C; }, between(-0.01, 0), "/C",
         "Relative change of the magnet flux per degree (NdFeB about -0.0012).");
  s.real("calibration.magnet_drift_C_per_sqrt_s", [](C& c) -> double& { return c.drive.magnet_drift_C_per_sqrt_s; },
         positive(100.0), "C/sqrt(s)",
         "How far the magnets may warm or cool between EMF measurements, as a random walk in thermal time: the "
         "magnet estimate's variance grows by its square per second. It sets how much a new measurement weighs "
         "against the last estimate (docs/estimator.md, the magnet temperature).");
  s.real("calibration.magnet_max_age_s", [](C& c) -> double& { return c.drive.magnet_max_age_s; }, positive(1e6), "s",
         "The magnet estimate is published as valid this long (thermal time) after its last EMF measurement; at "
         "standstill (time-based recordings) nothing measures it.");
  s.real("calibration.magnet_reference_max_std_C", [](C& c) -> double& { return c.drive.magnet_reference_max_std_C; },
         between(0, 10), "C",
         "A calibration run that measured no Ke0 (it ran at rest) takes one from the first turning events while the "
         "drive knows the rotor's temperature better than this standard uncertainty: the rotor between the ambient "
         "and the housing's estimate, so in the first minutes after the calibration. Every later magnet temperature "
         "carries that uncertainty in its band. 0: never; set it so for a rotor that carries much of the iron loss "
         "under a strongly cooled housing, which warms faster than the housing (docs/estimator.md, the magnet "
         "temperature).");
  // [derating]
  s.real("derating.max_current_A", [](C& c) -> double& { return c.drive.derating.max_current_A; }, positive(10000), "A",
         "|i| limit when cold (phase peak).");
  s.real("derating.min_current_A", [](C& c) -> double& { return c.drive.derating.min_current_A; }, at_least(0, 10000), "A",
         "Current limit at the temperature limit.");
  s.real("derating.start_C", [](C& c) -> double& { return c.drive.derating.derate_start_C; }, between(-50, 300), "C",
         "Derating begins where the upper bound of the estimate crosses this.");
  s.real("derating.limit_C", [](C& c) -> double& { return c.drive.derating.limit_C; }, between(-50, 300), "C", "Winding temperature limit.");
  s.real("derating.magnet_start_C", [](C& c) -> double& { return c.drive.derating.magnet_start_C; }, between(-50, 300), "C",
         "Magnet derating begins where the magnet estimate (from the EMF constant, docs/estimator.md section 8) crosses "
         "this; DRIVE_STATUS.LimitMagnetTemp says when it derates. An estimate that aged out keeps derating until a new "
         "one; before the first, nothing derates on the magnets.");
  s.real("derating.magnet_limit_C", [](C& c) -> double& { return c.drive.derating.magnet_limit_C; }, between(-50, 300), "C",
         "Magnet temperature at which the current limit reaches derating.min_current_A (default: an SH-grade NdFeB's "
         "150 C; N, M, H, UH, EH grades: 80, 100, 120, 180, 200 C).");
  s.real("derating.confidence_sigma", [](C& c) -> double& { return c.drive.derating.confidence_sigma; }, at_least(0, 10), "",
         "Derate on estimate + k sigma.");
  return s;
}

}  // namespace

const ConfigSchema<ControllerConfig>& controller_schema() {
  static const ConfigSchema<ControllerConfig> schema = build();
  return schema;
}

const std::vector<std::string>& controller_sections() {
  static const std::vector<std::string> sections{"motor", "sensors", "control", "injection", "estimator",
                                                 "thermal", "calibration", "derating"};
  return sections;
}

double speed_loop_rated_torque_Nm(const core::DriveConfig& d) {
  return core::torque_constant_dq_Nm_per_A(d.motor) * core::continuous_current_peak_A(d.motor);
}

double quantisation_limited_speed_bandwidth_rad_s(const core::DriveConfig& d) {
  return core::speed_bandwidth_for_quantisation_torque_rad_s(
      kSpeedLoopQuantisationTorqueShare * speed_loop_rated_torque_Nm(d), d.motor.inertia_kg_m2,
      d.angle.pll_bandwidth_rad_s, d.period_s, d.angle.encoder_bits);
}

ControllerConfig default_controller_config() {
  ControllerConfig c;
  finalize(c, "defaults");
  return c;
}

void finalize(ControllerConfig& c, std::string_view source, const toml::table* table, std::string_view key_prefix) {
  core::DriveConfig& d = c.drive;
  const core::MotorParams& m = d.motor;
  // The defaults that scale with the motor (exactly the Table I numbers at the Table I motor).
  const core::MotorRelativeDefaults relative = core::motor_relative_defaults(m);
  d.injection.f_A = c.relative.injection_f_A.value_or(relative.injection_f_A);
  d.injection.f_min_A = c.relative.injection_f_min_A.value_or(relative.injection_f_min_A);
  // The window is the winding's temperatures (-57 to 287 C on Table I) plus a motor cable's
  // resistance, which does not warm with it.
  const double cable_ohm = core::cable_resistance_at_C(d.thermal.cable_resistance_20C_ohm, m.rs_reference_temp_C);
  d.injection.rs_min_ohm = c.relative.rs_min_ohm.value_or(relative.rs_min_ohm + cable_ohm);
  d.injection.rs_max_ohm = c.relative.rs_max_ohm.value_or(relative.rs_max_ohm + cable_ohm);
  d.injection.max_load_change_A = c.relative.max_load_change_A.value_or(relative.max_load_change_A);
  d.injection.max_speed_change_rad_s = c.relative.max_speed_change_rad_s.value_or(relative.max_speed_change_rad_s);
  // The missing loss's prior and random walk: Table I's 50 W and 0.5 W/sqrt(s) in proportion to
  // the commissioned cooling path's conductance (1 / 0.125 K/W there: 50 W is what 6.25 K over
  // the ambient drives through it). dP stands for the cooling path's error and the heat the loss
  // model lacks, both of which go with the heat the machine sheds. Absolute, they let a 7 W pump
  // learn a missing loss of -9.6 W within a minute and read 9 C low (docs/accuracy.md, "Unseen
  // motors, third round").
  const double loss_ratio = core::ThermalModelConfig{}.housing_to_ambient_K_W / d.thermal.housing_to_ambient_K_W;
  d.thermal.initial_loss_error_std_W = c.relative.initial_loss_error_std_W.value_or(50.0 * loss_ratio);
  d.thermal.loss_error_process_std_W_per_sqrt_s =
      c.relative.loss_error_process_std_W_per_sqrt_s.value_or(0.5 * loss_ratio);
  // A fifth above rated: the reference's duty cycles run up to rated speed, and the supervisor's
  // OVERSPEED (1.5 x rated by default) stays well above what the limit lets the shaft reach.
  d.speed_limit_rad_s = c.relative.speed_limit_rad_s.value_or(1.2 * m.rated_speed_rad_s);
  if (!c.relative.max_speed_change_rad_s && d.thermal.cable_resistance_20C_ohm > 0.0) {
    // The fit's resistive signal is what the drive measures, Rs dId with a cable's share too.
    d.injection.max_speed_change_rad_s *= core::terminal_resistance_ohm(d) / m.rs_ohm;
  }
  // Field weakening's bound: past the characteristic current psi / Ld the d current weakens the
  // flux to nothing and then reverses it; and never more than the drive's current.
  d.field_weakening.max_current_A = c.relative.field_weakening_max_current_A.value_or(
      std::min(core::flux_linkage_Wb(m) / m.ld_H, d.derating.max_current_A));
  // A quarter of the acceleration the drive's torque limit gives the commissioned inertia: the
  // ramp's feed-forward takes at most a quarter of the torque, the rest is left for the load and
  // the loop. The PLL's speed lags a ramp by about a / its bandwidth, which the shaft carries
  // past the set-point when the ramp ends: half the acceleration overshot a 200 rad/s step of
  // the Table I motor by 3.9 %, a quarter by 1.8 %, an eighth by 0.9 % (DriveNode.ASpeedStep...).
  d.speed_ramp_rad_s2 = c.relative.speed_ramp_rad_s2.value_or(
      0.25 * std::min(core::torque_constant_dq_Nm_per_A(m) * d.derating.max_current_A, d.speed.max_torque_Nm) /
      m.inertia_kg_m2);
  c.calibration_f_A = c.relative.calibration_f_A.value_or(relative.calibration_f_A);
  // The window's period: an edge's inductive voltage k Ld F / Tw goes with the inductance and the
  // current, and at 4 ms a 0.1 H motor's edge asked more than its bus (docs/estimator.md §2).
  d.injection.tw_s = c.relative.tw_s.value_or(core::default_window_period_s(
      std::max(c.calibration_f_A, d.injection.f_A), m.ld_H, c.nominal_dc_bus_V / std::sqrt(3.0), d.injection.window));
  // What the margin keeps free (the dead-time compensation's dead_time f_pwm Vdc, the bus's
  // ripple and sag, the modulator's and the current loop's reserve) scales with the bus: the
  // Table I drive's 15 V at 650 V, as a share. An absolute 15 V was 58 % of a 48 V drive's
  // 26 V limit, where every pair from 200 rad/s on was a field-weakening pair
  // (docs/accuracy.md, "Two motors a new user would bring").
  d.injection.headroom_margin_V = c.relative.headroom_margin_V.value_or(core::default_headroom_margin_V(c.nominal_dc_bus_V));
  // Injection shares the drive's current budget with motoring (the derated limit at run time).
  d.injection.current_limit_A = d.derating.max_current_A;
  // A dead time is commissioned from the gate driver's data within about a fifth.
  d.injection.vx_bus_slope_std = c.relative.vx_bus_slope_std.value_or(0.2 * d.dead_time.dead_time_s / d.period_s);
  // A fast event's means go wrong with how far the rotor turns in a period (a 4 kHz blower at 14
  // periods a turn taught a wrong Vx), not with the speed alone (a 16 kHz saw at 754 rad/s
  // learns it right): the tested 600 rad/s, and more where the periods are short.
  d.injection.vx_learning_max_speed_rad_s = c.relative.vx_learning_max_speed_rad_s.value_or(
      std::max(kVxLearningMaxSpeed_rad_s, kVxLearningMaxAnglePerPeriod_rad / d.period_s));
  // The calibration procedure: the run-time settings, as fixed-magnitude bipolar at two levels.
  // (Its vx_initial_V is never used: set_config() keeps the scheduler's learned Vx.)
  d.calibration_injection = d.injection;
  d.calibration_injection.method = core::InjectionMethod::kFixedMagnitude;
  // Rs0 must not carry the field-weakening pairs' bias (docs/estimator.md §2): a calibration
  // at the voltage limit waits for headroom (and says so, by its timeout) instead.
  d.calibration_injection.field_weakening_pairs = false;
  // At no load the pulses' reluctance torque is the friction current's, and the calibration
  // learns Lq from the speed loop's answer to it: its pulses stay on the d-axis (a
  // compensation would use the Lq being learned; with it the salient calibration's Lq read
  // 1.4 % low on its seed).
  d.calibration_injection.torque_neutral = false;
  d.calibration_injection.separation = core::Separation::kBipolar;
  d.calibration_injection.levels = {1.0, 0.4, 0.0, 0.0};
  d.calibration_injection.level_count = 2;
  d.calibration_injection.f_A = c.calibration_f_A;
  d.inverter_sweep.max_current_A = 0.5 * c.calibration_f_A;
  d.inverter_sweep.max_speed_change_rad_s = d.injection.max_speed_change_rad_s;
  d.angle_check.level_A = 0.5 * c.calibration_f_A;
  d.angle_check.max_speed_change_rad_s = d.injection.max_speed_change_rad_s;
  // The speed loop's answer to a level's torque: about six of its time constants, so that
  // J dw/dt (the commissioned inertia, the PLL's slope) is a small part of the balance. With
  // two (0.033 s at 60 rad/s) the reference read +0.6 mrad and a salient machine +1.7 mrad of
  // offset it did not have; with six, -0.1 mrad on the reference (docs/estimator.md 6.1).
  // At most 0.5 s: the calibration's timeout waits while the check runs.
  d.angle_check.settle_s = std::clamp(6.0 / d.speed.bandwidth_rad_s, 0.05, 0.5);
  d.angle_check.min_speed_rad_s = d.injection.min_speed_for_angle_rad_s;
  if (c.angle_correction_rad) {
    d.calibration.angle_correction_measured = true;
    d.calibration.angle_correction_rad = *c.angle_correction_rad;
  }
  // The estimator's Vx is the bridge's error at the nominal bus, as its prior below is.
  d.vx_reference_bus_V = c.nominal_dc_bus_V;
  if (c.vx_initial_from_compensation) {
    d.injection.vx_initial_V = d.dead_time.dead_time_s / d.period_s * c.nominal_dc_bus_V + d.dead_time.device_drop_V;
  }
  // The flux map's two lists, when they agree in length and fit (the rules below name them
  // otherwise). The lists are the map's one source: a drive.motor.lq_map set in code is replaced.
  d.motor.lq_map = {};
  const std::size_t max_points = core::LqMap::kMaxPoints;
  if (!c.lq_map_H.empty() && c.lq_map_H.size() == c.lq_map_current_A.size() && c.lq_map_H.size() <= max_points) {
    std::copy(c.lq_map_current_A.begin(), c.lq_map_current_A.end(), d.motor.lq_map.current_A.begin());
    std::copy(c.lq_map_H.begin(), c.lq_map_H.end(), d.motor.lq_map.secant_H.begin());
    d.motor.lq_map.points = static_cast<int>(c.lq_map_H.size());
  }
  // Every sub-configuration's copy of the motor model and the period, in one place (core).
  d.derive_from_motor();

  // Rules that involve several keys. A message starts with the file and line of the first
  // key the file gives and names both keys, each with its value and where it comes from.
  auto given = [&](std::string_view key) { return table != nullptr && static_cast<bool>(table->at_path(key)); };
  auto location = [&](std::string_view key) {
    return given(key) ? common::key_location(*table, key, source) : std::string(source) + ": ";
  };
  auto lead = [&](std::string_view a, std::string_view b) { return given(a) || !given(b) ? a : b; };
  // (Strings appended piece by piece here: GCC 12 at -O3 takes "literal" + std::string&& for an
  // overlapping memcpy, a false -Wrestrict warning, GCC bug 105329.)
  auto ref = [&](std::string_view key, double v, std::string_view unit, std::string_view lead_key) {
    std::string out{key_prefix};
    out += key;
    out += " (";
    out += common::format_number(v);
    if (!unit.empty()) {
      out += ' ';
      out += unit;
    }
    if (key != lead_key) {
      if (given(key)) {
        const std::string where = location(key);
        out += ", ";
        out += std::string_view(where).substr(0, where.size() - 2);
      } else {
        out += ", its default";
      }
    }
    out += ')';
    return out;
  };
  // Every broken rule is reported, one line each (like the per-key errors of the schema).
  std::string errors;
  auto rule = [&](std::string_view a, std::string_view b, const std::string& text) {
    if (!errors.empty()) {
      errors += '\n';
    }
    errors += location(lead(a, b));
    errors += text;
  };

  // The files the drive writes, relative to the configuration's directory. Each is written
  // whole, so each must be a file of its own: a thermal state written over the calibration
  // loses the commissioning (the next start refuses the file), and either written over the
  // configuration loses that.
  if (table != nullptr) {
    const std::filesystem::path dir = std::filesystem::path(source).parent_path();
    for (std::string* file : {&c.calibration_file, &c.thermal_state_file}) {
      if (!file->empty() && std::filesystem::path(*file).is_relative()) {
        *file = std::filesystem::absolute(dir / *file).lexically_normal().string();
      }
    }
    const auto same = [](const std::string& a, const std::string& b) { return common::same_file(a, b); };
    const std::string config_file =
        source.empty() ? std::string() : std::filesystem::absolute(source).lexically_normal().string();
    const std::string cal_key = fmt::format("{}calibration.file", key_prefix);
    const std::string state_key = fmt::format("{}thermal.state_file", key_prefix);
    if (!c.calibration_file.empty() && !c.thermal_state_file.empty() && same(c.calibration_file, c.thermal_state_file)) {
      rule("thermal.state_file", "calibration.file",
           fmt::format("{} and {} name the same file ({}): the thermal state written there would replace the calibration, "
                       "and the next start would refuse it",
                       cal_key, state_key, c.calibration_file));
    }
    for (const auto& [key, prefixed, file] : {std::tuple<std::string_view, const std::string&, const std::string&>{
                                                  "calibration.file", cal_key, c.calibration_file},
                                              {"thermal.state_file", state_key, c.thermal_state_file}}) {
      if (!file.empty() && !config_file.empty() && same(file, config_file)) {
        rule(key, key, fmt::format("{} names this configuration file itself ({}): the drive would write over it", prefixed, file));
      }
    }
  }
  // Both ends given and crossed: that is the contradiction (else the resistance checks below
  // name the nameplate and the one end the file gives).
  const bool window_given = given("injection.rs_min_ohm") && given("injection.rs_max_ohm");
  if (window_given && d.injection.rs_min_ohm >= d.injection.rs_max_ohm) {
    const std::string_view l = lead("injection.rs_min_ohm", "injection.rs_max_ohm");
    rule("injection.rs_min_ohm", "injection.rs_max_ohm",
         ref("injection.rs_min_ohm", d.injection.rs_min_ohm, "ohm", l) + " must be below " +
             ref("injection.rs_max_ohm", d.injection.rs_max_ohm, "ohm", l));
  }
  // A nameplate resistance outside the plausibility window: every estimate near the reference
  // temperature would be rejected (the Table I window never lets a 1.6 ohm servo calibrate).
  // Likewise a stored Rs0, which holds at its own T0.
  // (A stored Rs0 is named only where the file gives it: by default it is the nameplate.)
  bool window_reported = window_given && d.injection.rs_min_ohm >= d.injection.rs_max_ohm;
  for (const std::string_view r : {std::string_view("motor.rs_ohm"), std::string_view("calibration.rs0_ohm")}) {
    if (r == "calibration.rs0_ohm" && !given(r)) {
      continue;
    }
    const double rs = r == "motor.rs_ohm" ? core::terminal_resistance_ohm(d) : d.calibration.rs0_ohm;
    for (const std::string_view end : {std::string_view("injection.rs_min_ohm"), std::string_view("injection.rs_max_ohm")}) {
      const bool lower = end == "injection.rs_min_ohm";
      const double limit = lower ? d.injection.rs_min_ohm : d.injection.rs_max_ohm;
      if (!window_reported && (lower ? rs < limit : rs > limit)) {
        const std::string_view l = lead(end, r);
        // (The nameplate with a motor cable: both named, and their sum the drive sees.)
        const std::string what = r == "motor.rs_ohm" && d.thermal.cable_resistance_20C_ohm > 0.0
                                     ? ref(r, m.rs_ohm, "ohm", l) + " with " +
                                           ref("motor.cable_resistance_ohm", d.thermal.cable_resistance_20C_ohm, "ohm", l) +
                                           fmt::format(" ({:.6g} ohm in all)", rs)
                                     : ref(r, rs, "ohm", l);
        rule(end, r,
             what + " lies " + (lower ? "below " : "above ") + ref(end, limit, "ohm", l) +
                 ": the plausibility window would reject every resistance estimate near the reference temperature");
        window_reported = true;
      }
    }
  }
  if (!window_reported && d.injection.rs_min_ohm >= d.injection.rs_max_ohm) {  // equal ends around the nameplate
    rule("injection.rs_min_ohm", "injection.rs_max_ohm", "injection.rs_min_ohm must be below injection.rs_max_ohm");
  }
  // A stored Rs0 holds the cable too (the drive measures both): it must leave the winding some.
  if (given("calibration.rs0_ohm")) {
    if (const std::string why = cable_leaves_no_winding(d.thermal.cable_resistance_20C_ohm, d.calibration); !why.empty()) {
      const std::string_view l = lead("motor.cable_resistance_ohm", "calibration.rs0_ohm");
      rule("motor.cable_resistance_ohm", "calibration.rs0_ohm",
           ref("motor.cable_resistance_ohm", d.thermal.cable_resistance_20C_ohm, "ohm", l) + why);
    }
  }
  // A stored Vx and its error bar go together: without the error bar (0 means "not learned")
  // the Vx would be silently ignored, and an error bar alone would make 0 V a certain prior.
  if (given("calibration.vx_V") && !(d.calibration.vx_std_V > 0.0)) {
    const std::string_view l = lead("calibration.vx_V", "calibration.vx_std_V");
    rule("calibration.vx_V", "calibration.vx_std_V",
         ref("calibration.vx_V", d.calibration.vx_V, "V", l) + " needs its standard error " +
             ref("calibration.vx_std_V", d.calibration.vx_std_V, "V", l) +
             " above 0: without it the stored bridge voltage is not used");
  } else if (d.calibration.vx_std_V > 0.0 && !given("calibration.vx_V")) {
    rule("calibration.vx_std_V", "calibration.vx_V",
         ref("calibration.vx_std_V", d.calibration.vx_std_V, "V", "calibration.vx_std_V") +
             " is the standard error of a stored calibration.vx_V, which is not given");
  }
  // The current loop's voltage limit at the nominal bus (a share of the space vector's
  // Vdc / sqrt(3) per phase): a margin that takes all of it leaves no voltage to inject with
  // at any speed.
  if (const double limit_V = core::voltage_limit_V(d.current, c.nominal_dc_bus_V);
      d.injection.headroom_margin_V >= limit_V) {
    const std::string_view l = lead("injection.headroom_margin_V", "control.nominal_dc_bus_V");
    rule("injection.headroom_margin_V", "control.nominal_dc_bus_V",
         ref("injection.headroom_margin_V", d.injection.headroom_margin_V, "V", l) + " must be below the voltage limit at the bus " +
             ref("control.nominal_dc_bus_V", c.nominal_dc_bus_V, "V", l) + ", " + common::format_number(limit_V) +
             " V (control.voltage_limit_fraction x bus / sqrt(3)): no injection could ever be budgeted");
  }
  // The field-weakening loop acts through the current loop: it must be the slower of the two by
  // far, or the two fight (its plant is the current loop's closed-loop response).
  if (d.field_weakening.bandwidth_rad_s > 0.5 * d.current.bandwidth_rad_s) {
    const std::string_view l = lead("control.field_weakening_bandwidth_rad_s", "control.current_bandwidth_rad_s");
    rule("control.field_weakening_bandwidth_rad_s", "control.current_bandwidth_rad_s",
         ref("control.field_weakening_bandwidth_rad_s", d.field_weakening.bandwidth_rad_s, "rad/s", l) +
             " must be at most half of " +
             ref("control.current_bandwidth_rad_s", d.current.bandwidth_rad_s, "rad/s", l) +
             ": the voltage loop acts through the current loop and must be the slower of the two");
  }
  // Saturation only lowers the secant inductance; the estimator's curve is kept within half of Lq.
  if (m.lq_rated_H > 0.0 && (m.lq_rated_H > m.lq_H || m.lq_rated_H < 0.5 * m.lq_H)) {
    const std::string_view l = lead("motor.lq_rated_H", "motor.lq_H");
    rule("motor.lq_rated_H", "motor.lq_H",
         ref("motor.lq_rated_H", m.lq_rated_H, "H", l) + " must lie between half of " + ref("motor.lq_H", m.lq_H, "H", l) +
             " and it: saturation lowers the secant inductance with load");
  }
  const bool map_given = !c.lq_map_current_A.empty() || !c.lq_map_H.empty();
  bool map_valid = m.lq_map.points > 0;
  if (c.lq_map_current_A.size() > max_points || c.lq_map_H.size() > max_points) {
    rule("motor.lq_map_H", "motor.lq_map_current_A",
         std::string(key_prefix) + "motor.lq_map_H and motor.lq_map_current_A take at most " + std::to_string(max_points) +
             " points, got " + std::to_string(c.lq_map_H.size()) + " and " + std::to_string(c.lq_map_current_A.size()));
  } else if (map_given && c.lq_map_current_A.size() != c.lq_map_H.size()) {
    rule("motor.lq_map_H", "motor.lq_map_current_A",
         std::string(key_prefix) + "motor.lq_map_H has " + std::to_string(c.lq_map_H.size()) + " points and " +
             std::string(key_prefix) + "motor.lq_map_current_A " + std::to_string(c.lq_map_current_A.size()) +
             ": one secant inductance per current");
  } else if (map_given && m.lq_rated_H > 0.0) {
    rule("motor.lq_map_H", "motor.lq_rated_H",
         std::string(key_prefix) + "motor.lq_map_H and " + std::string(key_prefix) +
             "motor.lq_rated_H are both given: the map's points replace its one point, give one of the two");
    map_valid = false;
  }
  for (int k = 1; k < m.lq_map.points; ++k) {
    const auto i = static_cast<std::size_t>(k);
    if (!(m.lq_map.current_A[i] > m.lq_map.current_A[i - 1])) {
      rule("motor.lq_map_current_A", "motor.lq_map_current_A",
           std::string(key_prefix) + "motor.lq_map_current_A must ascend: point " + std::to_string(k) + " (" +
               common::format_number(m.lq_map.current_A[i]) + " A) is not above point " + std::to_string(k - 1) + " (" +
               common::format_number(m.lq_map.current_A[i - 1]) + " A)");
      map_valid = false;
      break;
    }
  }
  for (int k = 0; k < m.lq_map.points; ++k) {
    const double secant = m.lq_map.secant_H[static_cast<std::size_t>(k)];
    if (!(secant <= m.lq_H && secant >= 0.5 * m.lq_H)) {
      const std::string_view l = lead("motor.lq_map_H", "motor.lq_H");
      rule("motor.lq_map_H", "motor.lq_H",
           std::string(key_prefix) + "motor.lq_map_H point " + std::to_string(k) + " (" + common::format_number(secant) +
               " H at " + common::format_number(m.lq_map.current_A[static_cast<std::size_t>(k)]) +
               " A) must lie between half of " + ref("motor.lq_H", m.lq_H, "H", l) +
               " and it: saturation lowers the secant inductance with load");
      map_valid = false;
    }
  }
  // Saturation only lowers the secant: a map that rises with current, or one whose last point
  // shows none (the curve is drawn through the loss at the last point), is not one the
  // estimator's curve can follow.
  if (map_valid) {
    const auto n = static_cast<std::size_t>(m.lq_map.points);
    for (std::size_t k = 1; k < n; ++k) {
      if (m.lq_map.secant_H[k] > m.lq_map.secant_H[k - 1]) {
        rule("motor.lq_map_H", "motor.lq_map_H",
             std::string(key_prefix) + "motor.lq_map_H must not rise with the current: point " + std::to_string(k) + " (" +
                 common::format_number(m.lq_map.secant_H[k]) + " H) is above point " + std::to_string(k - 1) + " (" +
                 common::format_number(m.lq_map.secant_H[k - 1]) + " H); saturation lowers the secant inductance");
        map_valid = false;
        break;
      }
    }
    if (map_valid && !(m.lq_map.secant_H[n - 1] < m.lq_H)) {
      const std::string_view l = lead("motor.lq_map_H", "motor.lq_H");
      rule("motor.lq_map_H", "motor.lq_H",
           std::string(key_prefix) + "motor.lq_map_H's last point (" + common::format_number(m.lq_map.secant_H[n - 1]) +
               " H) equals " + ref("motor.lq_H", m.lq_H, "H", l) +
               ": a map that shows no saturation says nothing the estimator can use; leave it out");
      map_valid = false;
    }
  }
  if ((m.lq_rated_H > 0.0 && m.lq_rated_H <= m.lq_H && m.lq_rated_H >= 0.5 * m.lq_H && !map_given) || map_valid) {
    // The estimator's curve extrapolates from the map's last point along its slope there (at most
    // three times the last segment's) to the current limit, and the secant there must stay above
    // half of Lq too.
    const double at_limit_H = core::LqShape(d.injection).commissioned_secant_H(d.injection.current_limit_A);
    if (at_limit_H < 0.5 * m.lq_H) {
      const std::string_view key = map_valid ? "motor.lq_map_H" : "motor.lq_rated_H";
      const std::string_view l = lead(key, "derating.max_current_A");
      const std::string what =
          map_valid ? std::string(key_prefix) + "motor.lq_map_H, extrapolated from its last point,"
                    : ref("motor.lq_rated_H", m.lq_rated_H, "H", l) + " at the rated current (" +
                          common::format_number(core::continuous_current_peak_A(m)) + " A peak)";
      rule(key, "derating.max_current_A",
           what + " implies a secant Lq of " + common::format_number(at_limit_H) + " H at " +
               ref("derating.max_current_A", d.derating.max_current_A, "A", l) +
               ", below half of motor.lq_H: more saturation than the estimator's curve, a - b s(iq), can follow");
    }
  }
  // Two keys, one order: "a (value, where) must be below b (value, where)".
  auto ordered = [&](std::string_view a, double va, std::string_view b, double vb, std::string_view unit,
                     std::string_view relation) {
    const std::string_view l = lead(a, b);
    rule(a, b, ref(a, va, unit, l) + " " + std::string(relation) + " " + ref(b, vb, unit, l));
  };
  if (d.derating.derate_start_C >= d.derating.limit_C) {
    ordered("derating.start_C", d.derating.derate_start_C, "derating.limit_C", d.derating.limit_C, "C", "must be below");
  }
  if (d.derating.magnet_start_C >= d.derating.magnet_limit_C) {
    ordered("derating.magnet_start_C", d.derating.magnet_start_C, "derating.magnet_limit_C", d.derating.magnet_limit_C, "C",
            "must be below");
  }
  // The current loop regulates what its ADCs measure: a limit at or beyond their range lets a
  // saturated reading stand for a current (and the daemon's overcurrent trip, 90 % of the range
  // by default, would come first).
  if (d.derating.max_current_A >= c.sensors.current_range_A) {
    ordered("derating.max_current_A", d.derating.max_current_A, "sensors.current_range_A", c.sensors.current_range_A, "A",
            "must be below");
  }
  if (d.derating.min_current_A > d.derating.max_current_A) {
    ordered("derating.min_current_A", d.derating.min_current_A, "derating.max_current_A", d.derating.max_current_A, "A",
            "must not exceed");
  }
  // The thermal filter's prediction is a second-order step per update: accurate while an
  // update's thermal time is a fraction of the model's fastest time constant, divergent beyond
  // twice it (an estimate of -1e96 C that reads as cold and derates nothing).
  if (const double tau_s = core::thermal_model_fastest_time_constant_s(d.thermal),
      step_s = d.thermal_update_s * d.thermal.time_scale;
      !(step_s <= core::kMaxThermalStepPerTimeConstant * tau_s)) {
    const std::string_view l = lead("thermal.update_s", "thermal.acceleration");
    rule("thermal.update_s", "thermal.acceleration",
         ref("thermal.update_s", d.thermal_update_s, "s", l) + " times " +
             ref("thermal.acceleration", d.thermal.time_scale, "", l) + " is " + common::format_number(step_s) +
             " s of thermal time per update, more than " + common::format_number(core::kMaxThermalStepPerTimeConstant) +
             " of the thermal model's fastest time constant, " + common::format_number(tau_s) +
             " s (thermal.winding_capacity_J_K with its resistances): the filter's prediction would be wrong, and "
             "beyond twice it diverge; shorten thermal.update_s or lower the acceleration");
  }
  // The current loop cancels the machine's pole (Kp = wc L, Ki = wc Rs) and its command takes
  // effect 1.5 periods later (a period of computation, half a period of PWM averaging): a lag
  // of 1.5 wc T at the crossover. At wc T = 0.5 that is 43 degrees, a phase margin of 47; the
  // default 2000 rad/s at 100 us is 0.2. At 2 (the default bandwidth at a 1 ms period) the
  // drive could not turn its shaft at all.
  if (const double wc_t = d.current.bandwidth_rad_s * d.period_s; wc_t > 0.5) {
    const std::string_view l = lead("control.current_bandwidth_rad_s", "control.period_s");
    rule("control.current_bandwidth_rad_s", "control.period_s",
         ref("control.current_bandwidth_rad_s", d.current.bandwidth_rad_s, "rad/s", l) + " times " +
             ref("control.period_s", d.period_s, "s", l) + " is " + common::format_number(wc_t) +
             ", above 0.5: with the command applied 1.5 periods late the current loop keeps less than 47 degrees of "
             "phase margin (lower the bandwidth to at most " +
             common::format_number(0.5 / d.period_s) + " rad/s, or shorten the period)");
  }
  // A cascade: the speed loop takes the current loop for instantaneous, which holds when the
  // inner loop is several times faster (the default 60 against 2000 rad/s).
  if (d.speed.bandwidth_rad_s > 0.2 * d.current.bandwidth_rad_s) {
    const std::string_view l = lead("control.speed_bandwidth_rad_s", "control.current_bandwidth_rad_s");
    rule("control.speed_bandwidth_rad_s", "control.current_bandwidth_rad_s",
         ref("control.speed_bandwidth_rad_s", d.speed.bandwidth_rad_s, "rad/s", l) + " must be at most a fifth of " +
             ref("control.current_bandwidth_rad_s", d.current.bandwidth_rad_s, "rad/s", l) +
             ": the speed loop would meet the current loop's lag and oscillate");
  }
  // The bridge: a dead time per edge pair, two edges a period. Its voltage error, the
  // estimator's prior for Vx, follows from the period and the bus; both must be physical.
  if (d.dead_time.dead_time_s >= 0.25 * d.period_s) {
    const std::string_view l = lead("control.dead_time_s", "control.period_s");
    rule("control.dead_time_s", "control.period_s",
         ref("control.dead_time_s", d.dead_time.dead_time_s, "s", l) + " must be below a quarter of " +
             ref("control.period_s", d.period_s, "s", l) + ": the bridge would spend half the period or more in dead time");
  } else if (c.vx_initial_from_compensation && std::abs(d.injection.vx_initial_V) > 50.0) {
    const std::string_view l = lead("control.dead_time_s", "control.nominal_dc_bus_V");
    rule("control.dead_time_s", "control.nominal_dc_bus_V",
         ref("control.dead_time_s", d.dead_time.dead_time_s, "s", l) + " / " + ref("control.period_s", d.period_s, "s", l) +
             " x " + ref("control.nominal_dc_bus_V", c.nominal_dc_bus_V, "V", l) + " + " + std::string(key_prefix) +
             "control.device_drop_V gives the bridge a voltage error of " + common::format_number(d.injection.vx_initial_V) +
             " V, beyond the +-50 V " + std::string(key_prefix) + "injection.vx_initial_V allows: set it, or check the dead time");
  }
  double smallest_level = 1.0;
  for (int k = 0; k < d.injection.level_count; ++k) {
    smallest_level = std::min(smallest_level, d.injection.levels[static_cast<std::size_t>(k)]);
  }
  if (d.injection.f_min_A > d.injection.f_A * smallest_level) {
    const std::string_view l = lead("injection.F_min_A", "injection.F_A");
    rule("injection.F_min_A", "injection.F_A",
         ref("injection.F_min_A", d.injection.f_min_A, "A", l) + " must not exceed " +
             ref("injection.F_A", d.injection.f_A, "A", l) + " times the smallest of injection.levels (" +
             common::format_number(smallest_level) + ")");
  }
  if (d.injection.f_min_A > c.calibration_f_A * 0.4) {
    const std::string_view l = lead("injection.F_min_A", "calibration.F_A");
    rule("injection.F_min_A", "calibration.F_A",
         ref("injection.F_min_A", d.injection.f_min_A, "A", l) + " must not exceed 0.4 " +
             ref("calibration.F_A", c.calibration_f_A, "A", l) + " (the calibration's smaller level)");
  }
  if (d.injection.settle_s + 2.0 * d.period_s > d.injection.record_time_s) {
    const std::string_view l = lead("injection.record_time_s", "injection.settle_s");
    rule("injection.record_time_s", "injection.settle_s",
         ref("injection.record_time_s", d.injection.record_time_s, "s", l) + " must be longer than " +
             ref("injection.settle_s", d.injection.settle_s, "s", l) + " by two control periods");
  }
  {
    // The recorder holds the longest recording asked for, in whole turns at the slowest
    // angle-based speed (one more turn at most), preallocated when the drive is built: 8192
    // samples at least, more on a fast drive. (It was 8192 whatever the rate, and the default
    // recordings, 0.33 s with the turn, did not fit a drive above 25 kHz: a 32 kHz spindle's
    // configuration with every injection key at its default was refused.) At most
    // kMaxRecordingSamples, 11.5 MB of rows.
    const double longest_s = std::max({d.injection.record_time_s, d.injection.record_min_time_s,
                                       d.injection.field_weakening_record_min_time_s}) +
                             2.0 * std::numbers::pi / d.injection.min_speed_for_angle_rad_s;
    const double samples = std::ceil(longest_s / d.period_s) + 1.0;
    if (!(samples <= static_cast<double>(kMaxRecordingSamples))) {
      rule("injection.field_weakening_record_min_time_s", "injection.record_min_time_s",
           fmt::format("recordings of up to {:.4g} s (the longest of injection.record_time_s, record_min_time_s and "
                       "field_weakening_record_min_time_s, plus one turn at injection.min_speed_for_angle_rad_s = {} rad/s) "
                       "do not fit the {:.4g} s the recorder can hold at control.period_s = {} s (at most {} samples)",
                       longest_s, common::format_number(d.injection.min_speed_for_angle_rad_s),
                       static_cast<double>(kMaxRecordingSamples) * d.period_s, common::format_number(d.period_s),
                       kMaxRecordingSamples));
    } else {
      d.recording_capacity = std::max(kMinRecordingSamples, static_cast<std::size_t>(samples));
    }
  }
  if (!errors.empty()) {
    throw ConfigError(errors);
  }
}

ControllerConfig parse_controller_config(const toml::table& table, std::string_view source,
                                         const std::vector<std::string>& foreign, std::string_view key_prefix) {
  ControllerConfig c;
  // A stored calibration defaults to the nameplate unless the file says otherwise.
  const bool rs0_given = static_cast<bool>(table.at_path("calibration.rs0_ohm"));
  const bool t0_given = static_cast<bool>(table.at_path("calibration.t0_C"));
  const bool rs0_std_given = static_cast<bool>(table.at_path("calibration.rs0_std_fraction"));
  c.vx_initial_from_compensation = !table.at_path("injection.vx_initial_V");
  // [controller.supervisor]: the supervisor's keys put under the drive's (a newcomer's first guess,
  // since [controller.*] is where every other drive key goes). Named with where they belong, beside
  // the section's other mistakes; "unknown key" alone left the reader to guess.
  std::string misplaced;
  std::vector<std::string> not_ours = foreign;
  if (const toml::node* node = key_prefix == "controller." ? table.get("supervisor") : nullptr; node != nullptr) {
    misplaced = common::node_location(*node, source) +
                "controller.supervisor: the supervisor's keys are a section of their own at the file's top level, "
                "[supervisor] (supervisor.dc_bus_max_V, ...), not under [controller]: move the section out";
    not_ours.emplace_back("supervisor");
  }
  try {
    controller_schema().apply(table, c, source, not_ours, key_prefix);
  } catch (const ConfigError& e) {
    throw ConfigError(misplaced.empty() ? std::string(e.what()) : misplaced + "\n" + e.what());
  }
  if (!misplaced.empty()) {
    throw ConfigError(misplaced);
  }
  if (!rs0_given) {
    c.drive.calibration.rs0_ohm = core::terminal_resistance_ohm(c.drive);  // the nameplate's and a cable's
  } else if (!rs0_std_given) {
    // A stored calibration's Rs0 (the key's meaning) was measured: no nameplate share.
    c.drive.calibration.rs0_std_fraction = 0.0;
  }
  if (!t0_given) {
    c.drive.calibration.t0_C = c.drive.motor.rs_reference_temp_C;
  }
  finalize(c, source, &table, key_prefix);
  return c;
}

std::string_view to_string(StoredCalibration s) {
  switch (s) {
    case StoredCalibration::kNotConfigured: return "not configured";
    case StoredCalibration::kLoaded: return "loaded";
    case StoredCalibration::kMissing: return "missing";
  }
  return "?";
}

StoredCalibration load_stored_calibration(ControllerConfig& config, StoredAxis* written_by) {
  if (config.calibration_file.empty()) {
    return StoredCalibration::kNotConfigured;
  }
  std::error_code ec;
  if (!std::filesystem::exists(config.calibration_file, ec)) {
    if (ec) {
      // Not "missing": a path that cannot be looked at (a symlink loop, a name too long, a
      // directory it may not enter) cannot be written either, and a calibration there would be
      // lost at its end.
      throw CalibrationFileError(fmt::format("{}: cannot be looked at ({})", config.calibration_file, ec.message()));
    }
    return StoredCalibration::kMissing;
  }
  const core::Calibration stored = read_calibration_file(config.calibration_file, written_by);
  // The file's own ranges are wide (any motor); against this drive's plausibility window a
  // stored Rs0 is held to the rule a configured calibration.rs0_ohm is (check_cross_keys): a
  // calibration of another motor, or a hand edit, would otherwise set every temperature (Eq. 1
  // refers each estimate to it) far off while each estimate passes the window.
  const core::InjectionConfig& inj = config.drive.injection;
  if (!(stored.rs0_ohm >= inj.rs_min_ohm && stored.rs0_ohm <= inj.rs_max_ohm)) {
    const bool low = stored.rs0_ohm < inj.rs_min_ohm;
    throw CalibrationFileError(fmt::format(
        "{}: rs0_ohm {} ohm lies {} the drive's plausibility window (controller.injection.{} = {} ohm): a calibration "
        "of another motor or a hand edit; every temperature would be referred to it. Calibrate again (remove the file) "
        "or correct the window",
        config.calibration_file, common::format_number(stored.rs0_ohm), low ? "below" : "above",
        low ? "rs_min_ohm" : "rs_max_ohm", common::format_number(low ? inj.rs_min_ohm : inj.rs_max_ohm)));
  }
  if (const std::string why = cable_leaves_no_winding(config.drive.thermal.cable_resistance_20C_ohm, stored);
      !why.empty()) {
    throw CalibrationFileError(fmt::format("{}: the configured controller.motor.cable_resistance_ohm ({} ohm at 20 C){}: "
                                           "correct the cable, or calibrate again (remove the file)",
                                           config.calibration_file,
                                           common::format_number(config.drive.thermal.cable_resistance_20C_ohm), why));
  }
  config.drive.calibration = stored;
  return StoredCalibration::kLoaded;
}

std::vector<std::string> configuration_warnings(const ControllerConfig& config) {
  std::vector<std::string> out;
  const core::DriveConfig& d = config.drive;
  const core::MotorParams table_i{};
  const double current_ratio = d.motor.continuous_current_A_rms / table_i.continuous_current_A_rms;
  const bool another_motor = current_ratio < 0.5 || current_ratio > 2.0;
  const core::ThermalModelConfig t0{};
  const core::ThermalModelConfig& t = d.thermal;
  if (another_motor && t.winding_capacity_J_K == t0.winding_capacity_J_K &&
      t.housing_capacity_J_K == t0.housing_capacity_J_K && t.winding_to_housing_K_W == t0.winding_to_housing_K_W &&
      t.housing_to_ambient_K_W == t0.housing_to_ambient_K_W && t.iron_loss_k1_W_s_rad == t0.iron_loss_k1_W_s_rad &&
      t.iron_loss_k2_W_s2_rad2 == t0.iron_loss_k2_W_s2_rad2) {
    const double w = table_i.rated_speed_rad_s;
    out.push_back(fmt::format(
        "controller.thermal: the thermal model has the reference machine's values ({:.1f} kW: winding {:.0f} J/K, "
        "housing {:.0f} J/K, {:.3f} and {:.3f} K/W, iron loss {:.0f} W at {:.0f} rad/s), for a motor of {:.1f} A RMS "
        "(controller.motor.continuous_current_A_rms; the reference's {:.1f} A): between measurements the estimate "
        "follows that model (docs/configuration.md, the thermal keys)",
        table_i.rated_power_W / 1e3, t0.winding_capacity_J_K, t0.housing_capacity_J_K, t0.winding_to_housing_K_W,
        t0.housing_to_ambient_K_W, t0.iron_loss_k1_W_s_rad * w + t0.iron_loss_k2_W_s2_rad2 * w * w, w,
        d.motor.continuous_current_A_rms, table_i.continuous_current_A_rms));
  }
  // A shaft fan's share or exponent given without its speed: no fan is modelled, and the share
  // the engineer read off the data sheet would be lost without a word.
  if (!(t.fan_speed_rad_s > 0.0) &&
      (t.fan_standstill_share != t0.fan_standstill_share || t.fan_exponent != t0.fan_exponent)) {
    out.push_back(fmt::format(
        "controller.thermal.fan_standstill_share = {:g} and fan_exponent = {:g} describe a shaft fan, but "
        "thermal.fan_speed_rad_s is 0 (no shaft fan): they are not used, and the housing's path to the ambient "
        "(thermal.housing_to_ambient_K_W) holds at every speed; give the fan's speed, the data sheet's rated speed "
        "(docs/configuration.md, \"A self-ventilated machine\")",
        t.fan_standstill_share, t.fan_exponent));
  }
  // A fan's speed far from the motor's rated speed: a data sheet's resistance to the ambient
  // holds at its rated speed, and a speed entered in Hz or in rpm would make the model's fan
  // six times too slow or ten times too fast (beyond its speed the model cools more: it reads
  // low).
  if (t.fan_speed_rad_s > 0.0 &&
      (t.fan_speed_rad_s < 0.5 * d.motor.rated_speed_rad_s || t.fan_speed_rad_s > 2.0 * d.motor.rated_speed_rad_s)) {
    out.push_back(fmt::format(
        "controller.thermal.fan_speed_rad_s = {:g} rad/s lies far from controller.motor.rated_speed_rad_s = {:g} rad/s: "
        "thermal.housing_to_ambient_K_W holds at the fan's speed, which is the data sheet's rated speed in mechanical "
        "rad/s (a speed in Hz or rpm moves where the model's cooling is full; docs/configuration.md, \"A self-ventilated "
        "machine\")",
        t.fan_speed_rad_s, d.motor.rated_speed_rad_s));
  }
  // Without field weakening (control.field_weakening, off by default) the drive reaches no speed
  // whose EMF takes more than the voltage the bus allows (docs/daemon.md, "Field weakening").
  const double emf_speed_rad_s =
      core::voltage_limit_V(d.current, config.nominal_dc_bus_V) / core::emf_constant_dq_V_s_per_rad(d.motor);
  if (!d.field_weakening.enabled && d.motor.rated_speed_rad_s > emf_speed_rad_s) {
    out.push_back(fmt::format(
        "controller.motor.rated_speed_rad_s = {:g} rad/s lies beyond the {:.0f} rad/s where the EMF (motor.ke_V_s_per_rad) "
        "takes the whole voltage control.nominal_dc_bus_V = {:g} V allows (control.voltage_limit_fraction x bus / "
        "sqrt 3): without control.field_weakening = true the drive does not reach it, and set-points beyond it are "
        "best kept out, since the injection's pulses can carry the shaft there (docs/daemon.md)",
        d.motor.rated_speed_rad_s, emf_speed_rad_s, config.nominal_dc_bus_V));
  }
  // The speed loop's answer to the encoder's resolution: the torque noise its gain makes of the
  // PLL's speed (docs/daemon.md, "The speed loop and the encoder").
  if (const double rated_Nm = speed_loop_rated_torque_Nm(d), quiet_rad_s = quantisation_limited_speed_bandwidth_rad_s(d);
      d.speed.bandwidth_rad_s > quiet_rad_s * (1.0 + 1e-9)) {
    const double noise_Nm = core::speed_loop_quantisation_torque_Nm(
        d.motor.inertia_kg_m2, d.speed.bandwidth_rad_s, d.angle.pll_bandwidth_rad_s, d.period_s, d.angle.encoder_bits);
    out.push_back(fmt::format(
        "controller.control.speed_bandwidth_rad_s = {:g} rad/s: the speed loop's gain (motor.inertia_kg_m2 = {:g} kg m^2 "
        "x the bandwidth) turns the {}-bit encoder's rounding, read through the PLL's speed "
        "(control.pll_bandwidth_rad_s = {:g} rad/s), into {:.3g} N m RMS of torque demand, {:.1f} % of the rated "
        "{:.3g} N m; it would be {:.0f} %, where this warning starts, at {:.3g} rad/s. The noise is in the current "
        "and the shaft's torque, and its peaks take current the load needs: a lower bandwidth, a lower PLL bandwidth (the noise goes with it; keep it several "
        "times the speed loop's) or a finer encoder (docs/daemon.md, \"The speed loop and the encoder\")",
        d.speed.bandwidth_rad_s, d.motor.inertia_kg_m2, d.angle.encoder_bits, d.angle.pll_bandwidth_rad_s, noise_Nm,
        100.0 * noise_Nm / rated_Nm, rated_Nm, 100.0 * kSpeedLoopQuantisationTorqueShare, quiet_rad_s));
  }
  if (d.estimator == core::EstimatorKind::kInjection) {
    if (const std::string w = salient_method_warning(d, d.injection.method, d.injection.separation); !w.empty()) {
      out.push_back("controller.injection: " + w);
    }
    if (const std::string w = salient_flux_map_warning(config); !w.empty()) {
      out.push_back("controller.motor: " + w);
    }
  }
  const double rated_peak_A = core::continuous_current_peak_A(d.motor);
  if (d.derating.min_current_A > rated_peak_A) {
    out.push_back(fmt::format(
        "controller.derating.min_current_A = {:g} A lies above the motor's rated peak current ({:.2f} A: "
        "continuous_current_A_rms {:g} A x sqrt 2): at derating.limit_C the drive still allows more than the winding "
        "can carry for good, so it keeps heating past its limit",
        d.derating.min_current_A, rated_peak_A, d.motor.continuous_current_A_rms));
  }
  return out;
}

std::string pair_rejection_advice(const core::OutcomeCounts& counts, const core::DriveConfig& d) {
  using core::PairOutcome;
  const auto n = [&counts](PairOutcome o) { return std::uint64_t{counts[static_cast<std::size_t>(o)]}; };
  const std::uint64_t speed_changes = n(PairOutcome::kRejectedSpeedChange);
  const std::uint64_t load_changes = n(PairOutcome::kRejectedLoadChange);
  const std::uint64_t moved = speed_changes + load_changes;
  std::uint64_t pairs = 0;
  for (std::size_t k = 0; k < counts.size(); ++k) {
    pairs += core::pair_judged(static_cast<PairOutcome>(k)) ? counts[k] : 0U;
  }
  if (pairs < kPairRejectionAdviceMinPairs || 2 * moved < pairs) {
    return {};
  }
  std::string text = fmt::format(
      "{} of {} injection pairs judged were rejected because the speed ({}) or the load ({}) changed between their two "
      "recordings, so the winding is measured rarely and the thermal model carries the estimate. Either the duty "
      "cycle leaves few steady spells of a pair's length (the guards: injection.max_speed_change_fraction, "
      "injection.max_speed_change_rad_s, injection.max_load_change_A)",
      moved, pairs, speed_changes, load_changes);
  const double ld_H = d.current.ld_H;
  const double lq_H = d.current.lq_H;
  if (!(d.injection.max_torque_disturbance_Nm > 0.0) && ld_H > 0.0 && lq_H > 0.0) {
    // 3/2 p (Ld - Lq) F iq: the pulse's reluctance torque changes sign between a bipolar pair's
    // recordings, and the speed loop's answer to it moves the speed and iq between them. Named
    // whatever the commissioned inductances say: their errors can hide a saliency (measured:
    // unseen round 6's c3, Lq 1.18 Ld on the machine, 0.95 Ld commissioned). On a surface-magnet
    // rotor a torque budget only limits the pulses under load, hence the "if".
    text += fmt::format(
        ", or, if the rotor has interior or inset magnets whatever the commissioned Lq / Ld ({:.3g}) says, each "
        "pulse's reluctance torque, 3/2 p (Ld - Lq) F iq, moves the shaft: with a torque budget "
        "(injection.max_torque_disturbance_Nm) fixed-magnitude pulses hold the torque (injection.torque_neutral; "
        "docs/configuration.md)",
        lq_H / ld_H);
  }
  return text + ".";
}

std::string salient_method_warning(const core::DriveConfig& d, core::InjectionMethod method, core::Separation separation) {
  // On a machine configured as salient, only fixed-magnitude pulses hold the torque (the
  // torque-neutral pulses), and only bipolar pairs cancel the bridge's error that is even in the
  // pulse (a unipolar pair's two recordings see the sign pattern at the motoring point and
  // beside it, and the EMF's harmonics in the currents move that pattern's error with the
  // current's angle). Measured: docs/accuracy.md, "The robustness suite under the other methods".
  if (!(d.injection.max_torque_disturbance_Nm > 0.0) || method == core::InjectionMethod::kNone ||
      (method == core::InjectionMethod::kFixedMagnitude && separation == core::Separation::kBipolar)) {
    return {};
  }
  const double budget_Nm = d.injection.max_torque_disturbance_Nm;
  if (method == core::InjectionMethod::kDc) {
    return fmt::format(
        "method = \"dc\" on a machine configured as salient (injection.max_torque_disturbance_Nm = {:g} N m): DC "
        "injection holds no torque budget and disturbs the torque by more than the rated value on the reference "
        "motor already; only fixed-magnitude bipolar pairs hold the torque and cancel the bridge's voltage error that "
        "is even in the pulse (docs/accuracy.md, \"The robustness suite under the other methods\")",
        budget_Nm);
  }
  return fmt::format(
      "method = \"{}\", separation = \"{}\" on a machine configured as salient (injection.max_torque_disturbance_Nm "
      "= {:g} N m): only fixed-magnitude pulses hold the torque (the torque-neutral pulses), and only bipolar pairs "
      "cancel the bridge's voltage error that is even in the pulse; on the 30 mohm IPM of the robustness suite each of "
      "the three other pair methods measured read the winding 8-19 C RMS off, low on average, its error band holding "
      "the truth as little as 84 % of the time (docs/accuracy.md, \"The robustness suite under the other methods\")",
      core::to_string(method), core::to_string(separation), budget_Nm);
}

double incremental_lq_sensitivity(const core::DriveConfig& d, double speed_rad_s) {
  // A torque-neutral pulse moves iq by iq (Lq - Ld) dId / psi to first order (the torque
  // iq (psi + (Ld - Lq) id) held), so a bipolar pair's d-axis fit holds w Lq,inc diq beside the
  // resistive Rs dId: their ratio, at the rated current and this speed with the commissioned
  // values, is what a relative error of the incremental Lq reads as in Rs (docs/estimator.md
  // section 2, "Tried and not kept: a budget on the compensation's error").
  const double psi_Wb = core::flux_linkage_Wb(d.motor);
  const double omega_e = d.motor.pole_pairs * speed_rad_s;
  const double iq_A = core::continuous_current_peak_A(d.motor);
  const double rho = omega_e * d.motor.lq_H * iq_A * std::abs(d.motor.lq_H - d.motor.ld_H) / (psi_Wb * d.motor.rs_ohm);
  return std::isfinite(rho) ? rho : 0.0;
}

double incremental_lq_sensitivity_speed_rad_s(const ControllerConfig& config) {
  // The rated speed, or below it the speed where the rated current on the q axis (id = 0) takes
  // the whole voltage, w_e sqrt(psi^2 + (Lq iq)^2) (Rs iq left out): beyond it the drive weakens
  // the field and the rated current no longer goes into iq alone.
  const core::DriveConfig& d = config.drive;
  const double psi_Wb = core::flux_linkage_Wb(d.motor);
  const double lq_iq_Wb = d.motor.lq_H * core::continuous_current_peak_A(d.motor);
  const double base_rad_s =
      core::voltage_limit_V(d.current, config.nominal_dc_bus_V) / (d.motor.pole_pairs * std::hypot(psi_Wb, lq_iq_Wb));
  return std::isfinite(base_rad_s) ? std::min(d.motor.rated_speed_rad_s, base_rad_s) : d.motor.rated_speed_rad_s;
}

std::string salient_flux_map_warning(const ControllerConfig& config) {
  const core::DriveConfig& d = config.drive;
  if (!(d.injection.max_torque_disturbance_Nm > 0.0) || !d.injection.torque_neutral ||
      d.injection.method != core::InjectionMethod::kFixedMagnitude || d.motor.lq_map.points > 0 ||
      d.motor.lq_rated_H > 0.0) {
    return {};
  }
  const double speed_rad_s = incremental_lq_sensitivity_speed_rad_s(config);
  const double rho = incremental_lq_sensitivity(d, speed_rad_s);
  if (!(rho >= kIncrementalLqSensitivityWarning)) {
    return {};
  }
  return fmt::format(
      "a salient machine (injection.max_torque_disturbance_Nm = {:g} N m) with torque-neutral pulses "
      "(injection.torque_neutral) and no flux map (motor.lq_map_current_A and motor.lq_map_H, or motor.lq_rated_H): "
      "each pulse moves iq with its d current, and a pair's Rs takes the incremental Lq's error with it: at the rated "
      "current ({:.3g} A peak) and {:.0f} rad/s (the rated speed, or where the rated current takes the whole voltage "
      "if lower) each 1 % of that error reads as {:.1f} % of Rs, in proportion to the speed and to iq (a per cent of "
      "a copper winding's Rs is about 2.6 K). Pairs at one load measure the secant Lq; until pairs at loads far apart "
      "resolve the curve the drive takes the incremental Lq as that secant, which lies above it on a saturating "
      "machine: its estimates read high by the gap while the machine motors, and low by as much while it generates "
      "(braking, lowering), the band saying so; two loads give the curve's slope, and only a third its bend. On the "
      "robustness suite's 30 mohm IPM, after a heavy spell, a cruise at 314 rad/s read the winding 5 C high motoring "
      "and 4.5 C low braking (22 and 17 C before listening pairs anchored the curve at the heavy load), within 1 C with "
      "its map (docs/configuration.md, \"An interior-magnet machine: give its flux map\"; a salient rotor that does "
      "not saturate says so with motor.lq_rated_H = motor.lq_H)",
      d.injection.max_torque_disturbance_Nm, core::continuous_current_peak_A(d.motor), speed_rad_s, rho);
}

std::string t0_rise_text(const core::Calibration& c) {
  if (!(c.t0_rise_std_C > 0.0)) {
    return {};
  }
  return fmt::format(" (+- {:.2f} K: the ambient plus the thermal model's rise, calibration.model_rise_std_fraction)",
                     c.t0_rise_std_C);
}

std::string calibration_events_text(int used, int wanted) {
  if (used <= 0 || used >= wanted) {
    return {};
  }
  return fmt::format(" on {} of {} events, at its timeout (calibration.min_events)", used, wanted);
}

std::string cut_short_calibration_text(int used, int wanted, const core::OutcomeCounts& pairs,
                                       const core::AbortCounts& aborts, core::EstimatorKind kind) {
  std::string text = calibration_events_text(used, wanted);
  if (!text.empty()) {
    text += calibration_pairs_text(kind, pairs, aborts);
  }
  return text;
}

std::string calibration_pairs_text(core::EstimatorKind kind, const core::OutcomeCounts& pairs,
                                   const core::AbortCounts& aborts) {
  return kind == core::EstimatorKind::kInjection ? "; its pairs: " + core::pair_outcomes_text(pairs, aborts) : std::string{};
}

std::string rs_outside_window_text(const core::DriveConfig& d, double measured_ohm, double scatter_ohm) {
  const core::InjectionConfig& w = d.calibration_injection;
  const double nameplate_ohm = core::terminal_resistance_ohm(d);
  const double ratio = measured_ohm / nameplate_ohm;
  std::string text = fmt::format(
      "its {} events in a row measured Rs {:.4g} ohm (+- {:.2g}), {} the plausibility window {:.4g}-{:.4g} ohm "
      "(injection.rs_min_ohm, injection.rs_max_ohm) that motor.rs_ohm = {:g} ohm at {:g} C sets{}: the nameplate is "
      "not this winding's ({:.2f} times it). ",
      core::kCalibrationOutsideWindowEvents, measured_ohm, scatter_ohm,
      measured_ohm < w.rs_min_ohm ? "below" : "above", w.rs_min_ohm, w.rs_max_ohm, d.motor.rs_ohm,
      d.motor.rs_reference_temp_C,
      d.thermal.cable_resistance_20C_ohm > 0.0 ? fmt::format(" with motor.cable_resistance_ohm = {:g} ohm", d.thermal.cable_resistance_20C_ohm)
                                               : std::string(),
      ratio);
  if (ratio > 0.4 && ratio < 0.62) {
    text += "About half: a datasheet's line-to-line (terminal-to-terminal) resistance entered as motor.rs_ohm reads "
            "twice the phase value the drive wants; enter half of it, and check motor.ld_H and motor.lq_H, whose "
            "line-to-line values are twice theirs too (or one of two parallel paths' resistance was entered).";
  } else if (ratio > 1.6 && ratio < 2.5) {
    text += "About twice: check that motor.rs_ohm is the whole phase's resistance to the star point (not one of its "
            "coils in series) and that a motor cable is configured (motor.cable_resistance_ohm).";
  } else if (ratio < 0.003 || ratio > 300.0) {
    text += "By a factor near a thousand: motor.rs_ohm is in ohm, not milliohm.";
  } else {
    text += "Check motor.rs_ohm (phase to star point, at motor.rs_reference_temp_C), its unit, and a motor cable "
            "(motor.cable_resistance_ohm).";
  }
  return text;
}

}  // namespace pmsm::app
