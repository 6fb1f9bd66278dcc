// pmsm_step_cost: the drive's work in each control period, step by step, for the worst-case
// budget (bench/step-cost.sh runs it under callgrind; see docs/performance.md).
//
//   pmsm_step_cost [SCENARIO.toml] [SIMULATED_SECONDS]
//
// Runs a scenario's closed loop (the plant library and app::DriveNode, as `pmsm-thermal
// simulate` does) and, after every DriveNode::step(), asks callgrind to dump its counters
// with a label "step K CLASS". Under callgrind with --collect-atstart=no and
// --toggle-collect=<the step function>, each dump then holds exactly the instructions of one
// step of that function (DriveNode::step for the daemon's whole per-sample path, or
// DriveController::step for the controller alone); outside valgrind the client requests do
// nothing and the program prints how many steps of each class it ran.
//
// CLASS says what the step did, judged from the controller's telemetry before and after it
// (the most significant first): event (an injection event finished: fits, estimate, filter),
// pair (a pair of recordings completed: its fit), transition (the scheduler changed phase:
// a pair starts, a recording starts or ends), calibration (calibration started or ended),
// injecting (inside an injection, no transition), idle.
#include <valgrind/callgrind.h>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <numeric>
#include <string>

#include "drive_node.hpp"
#include "pmsm/core/drive_controller.hpp"
#include "pmsm/plant/plant.hpp"
#include "scenario.hpp"

namespace {

enum class StepClass : std::uint8_t { kIdle, kInjecting, kTransition, kCalibration, kPair, kEvent, kCount };

constexpr std::array<const char*, static_cast<std::size_t>(StepClass::kCount)> kClassNames{
    "idle", "injecting", "transition", "calibration", "pair", "event"};

struct Snapshot {
  pmsm::core::SchedulerPhase phase = pmsm::core::SchedulerPhase::kIdle;
  bool injecting = false;
  bool calibrating = false;
  std::uint64_t pairs = 0;
  std::uint64_t events = 0;
};

Snapshot snapshot(const pmsm::core::DriveTelemetry& t) {
  Snapshot s;
  s.phase = t.injection_phase;
  s.injecting = t.injection_active;
  s.calibrating = t.calibrating;
  s.pairs = std::accumulate(t.outcomes.begin(), t.outcomes.end(), std::uint64_t{0});
  s.events = static_cast<std::uint64_t>(t.estimates_published) + t.events_without_estimate;
  return s;
}

StepClass classify(const Snapshot& before, const Snapshot& after) {
  if (after.events != before.events) {
    return StepClass::kEvent;
  }
  if (after.pairs != before.pairs) {
    return StepClass::kPair;
  }
  if (after.calibrating != before.calibrating) {
    return StepClass::kCalibration;
  }
  if (after.phase != before.phase) {
    return StepClass::kTransition;
  }
  if (before.injecting || after.injecting || after.phase != pmsm::core::SchedulerPhase::kIdle) {
    return StepClass::kInjecting;
  }
  return StepClass::kIdle;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace pmsm;
  try {
    const std::filesystem::path path =
        argc > 1 ? std::filesystem::path(argv[1])
                 : std::filesystem::path(PMSM_SOURCE_DIR) / "bench/scenarios/reference-fm-bipolar.toml";
    const double seconds = argc > 2 ? std::strtod(argv[2], nullptr) : 3.0;
    if (!(seconds > 0.0 && seconds <= 3600.0)) {
      std::fprintf(stderr, "pmsm_step_cost: SIMULATED_SECONDS must be in (0, 3600], not '%s'\n", argv[2]);
      return 2;
    }
    const app::Scenario scenario = app::load_scenario(path);
    const app::ScenarioConfig& sc = scenario.scenario;
    plant::Plant plant(scenario.plant);
    app::DriveNode node(scenario.controller, app::default_supervisor_config(scenario.controller), app::PublishRates{});
    const core::DriveController& drive = node.controller();
    const auto periods = static_cast<std::uint64_t>(seconds / plant.period_s() + 0.5);

    std::array<std::uint64_t, static_cast<std::size_t>(StepClass::kCount)> counts{};
    bool calibration_started = false;
    char label[64];
    // PMSM_STEP_COST_PROFILE=1: no dumps, so that callgrind's one profile covers every step
    // (callgrind_annotate then shows where the nominal step's instructions go).
    const char* profile = std::getenv("PMSM_STEP_COST_PROFILE");
    const bool dump = profile == nullptr || std::string(profile) != "1";
    for (std::uint64_t k = 0; k < periods; ++k) {
      const double t = plant.time_s();
      app::NodeInputs in;
      in.mode = sc.mode;
      in.speed_ref_rad_s = sc.speed_rad_s.at(t);
      in.torque_ref_Nm = sc.torque_Nm.at(t);
      in.ambient_C = sc.ambient_profile.empty() ? sc.ambient_C : sc.ambient_profile.at(t);
      if (sc.calibrate && !calibration_started && t >= sc.calibrate_at_s) {
        in.start_calibration = true;
        calibration_started = true;
      }
      const Snapshot before = snapshot(drive.telemetry());
      const app::NodeStep& step = node.step(&plant.sample(), in);
      const StepClass c = classify(before, snapshot(drive.telemetry()));
      ++counts[static_cast<std::size_t>(c)];
      std::snprintf(label, sizeof label, "step %llu %s", static_cast<unsigned long long>(k),
                    kClassNames[static_cast<std::size_t>(c)]);
      if (dump) {
        CALLGRIND_DUMP_STATS_AT(label);
      }
      if (!step.command) {
        std::fprintf(stderr, "pmsm_step_cost: no command at step %llu\n", static_cast<unsigned long long>(k));
        return 1;
      }
      plant.step(*step.command);
    }
    std::printf("pmsm_step_cost: %s, %llu steps:", path.filename().c_str(), static_cast<unsigned long long>(periods));
    for (std::size_t i = 0; i < counts.size(); ++i) {
      std::printf(" %s %llu", kClassNames[i], static_cast<unsigned long long>(counts[i]));
    }
    std::printf("\n");
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "pmsm_step_cost: %s\n", e.what());
    return 2;
  }
}
