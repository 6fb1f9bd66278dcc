// A scenario's closed loop replayed step by step (the plant library and app::DriveNode, as
// `pmsm-thermal simulate` runs it), each step labelled with what the drive did in it. Shared
// by pmsm_step_cost (instructions per step under callgrind) and the step benchmark of
// pmsm_speed_bench (time per step by class).
//
// A step's class, judged from the controller's telemetry before and after it (the most
// significant first): event (an injection event finished: fits, estimate, filter), pair (a
// pair of recordings completed: its fit), calibration (calibration started or ended),
// transition (the scheduler changed phase: a pair starts, a recording starts or ends),
// sweep (the calibration's bridge sweep: a level, or one of its fits), injecting (inside an
// injection, no transition), idle.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <numeric>
#include <stdexcept>
#include <string>

#include "drive_node.hpp"
#include "pmsm/core/drive_controller.hpp"
#include "pmsm/plant/plant.hpp"
#include "scenario.hpp"

namespace pmsm::bench {

enum class StepClass : std::uint8_t { kIdle, kInjecting, kTransition, kCalibration, kPair, kEvent, kSweep, kCount };
inline constexpr std::size_t kStepClassCount = static_cast<std::size_t>(StepClass::kCount);
inline constexpr std::array<const char*, kStepClassCount> kStepClassNames{
    "idle", "injecting", "transition", "calibration", "pair", "event", "sweep"};

class StepReplay {
 public:
  explicit StepReplay(const std::filesystem::path& scenario_path)
      : scenario_(app::load_scenario(scenario_path)),
        plant_(scenario_.plant),
        node_(scenario_.controller, scenario_.supervisor, app::PublishRates{}) {}

  [[nodiscard]] double period_s() const { return plant_.period_s(); }

  // One control period: the scenario's inputs, then `run(node, sample, inputs)` must call
  // node.step(&sample, inputs) once and return its NodeStep (the caller wraps it: a timer,
  // callgrind's dump), then the plant steps. Throws if the drive answered nothing.
  template <class Run>
  StepClass step(Run&& run) {
    const app::ScenarioConfig& sc = scenario_.scenario;
    const double t = plant_.time_s();
    app::NodeInputs in;
    in.mode = sc.mode;
    in.speed_ref_rad_s = sc.speed_rad_s.at(t);
    in.torque_ref_Nm = sc.torque_Nm.at(t);
    in.ambient_C = sc.ambient_profile.empty() ? sc.ambient_C : sc.ambient_profile.at(t);
    if (sc.calibrate && !calibration_started_ && t >= sc.calibrate_at_s) {
      in.start_calibration = true;
      calibration_started_ = true;
    }
    const Telemetry before = snapshot(node_.controller().telemetry());
    const app::NodeStep& out = run(node_, plant_.sample(), in);
    const StepClass c = classify(before, snapshot(node_.controller().telemetry()));
    if (!out.command) {
      throw std::runtime_error("no inverter command at t = " + std::to_string(t) + " s");
    }
    plant_.step(*out.command);
    return c;
  }

 private:
  struct Telemetry {
    core::SchedulerPhase phase = core::SchedulerPhase::kIdle;
    bool injecting = false;
    bool calibrating = false;
    bool sweeping = false;
    std::uint64_t pairs = 0;
    std::uint64_t events = 0;
  };

  static Telemetry snapshot(const core::DriveTelemetry& t) {
    Telemetry s;
    s.phase = t.injection_phase;
    s.injecting = t.injection_active;
    s.calibrating = t.calibrating;
    s.sweeping = t.inverter_sweep_active;
    s.pairs = std::accumulate(t.outcomes.begin(), t.outcomes.end(), std::uint64_t{0});
    s.events = static_cast<std::uint64_t>(t.estimates_published) + t.events_without_estimate;
    return s;
  }

  static StepClass classify(const Telemetry& before, const Telemetry& after) {
    if (after.events != before.events) return StepClass::kEvent;
    if (after.pairs != before.pairs) return StepClass::kPair;
    if (after.calibrating != before.calibrating) return StepClass::kCalibration;
    if (after.phase != before.phase) return StepClass::kTransition;
    if (before.sweeping || after.sweeping) return StepClass::kSweep;  // the calibration's bridge sweep
    if (before.injecting || after.injecting || after.phase != core::SchedulerPhase::kIdle) return StepClass::kInjecting;
    return StepClass::kIdle;
  }

  app::Scenario scenario_;
  plant::Plant plant_;
  app::DriveNode node_;
  bool calibration_started_ = false;
};

}  // namespace pmsm::bench
