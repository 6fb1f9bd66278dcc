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
// CLASS says what the step did (bench/step_replay.hpp).
#include <valgrind/callgrind.h>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <string>
#include <vector>

#include "step_replay.hpp"

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
    bench::StepReplay replay(path);
    const auto periods = static_cast<std::uint64_t>(seconds / replay.period_s() + 0.5);

    std::array<std::uint64_t, bench::kStepClassCount> counts{};
    char label[64];
    // PMSM_STEP_COST_PROFILE=1: no dumps, so that callgrind's one profile covers every step
    // (callgrind_annotate then shows where the nominal step's instructions go).
    // PMSM_STEP_COST_PROFILE=CLASS (e.g. injecting): no dumps, and collection only in the steps
    // of that class. The replay is deterministic, so a first pass outside collection learns
    // each step's class and the second collects the chosen ones (run callgrind with
    // --collect-atstart=no and no --toggle-collect).
    const char* profile = std::getenv("PMSM_STEP_COST_PROFILE");
    const std::string profile_class = profile == nullptr ? std::string() : std::string(profile);
    const bool dump = profile_class.empty();
    std::vector<bench::StepClass> classes;
    std::size_t chosen = bench::kStepClassCount;
    for (std::size_t i = 0; i < bench::kStepClassCount; ++i) {
      if (profile_class == bench::kStepClassNames[i]) chosen = i;
    }
    if (chosen < bench::kStepClassCount) {
      bench::StepReplay first(path);
      classes.reserve(periods);
      for (std::uint64_t k = 0; k < periods; ++k) {
        classes.push_back(first.step([](app::DriveNode& node, const hal::SensorSample& sample,
                                        const app::NodeInputs& in) -> const app::NodeStep& {
          return node.step(&sample, in);
        }));
      }
    } else if (!dump && profile_class != "1") {
      std::fprintf(stderr, "pmsm_step_cost: PMSM_STEP_COST_PROFILE must be 1 or a step class, not '%s'\n",
                   profile_class.c_str());
      return 2;
    }
    for (std::uint64_t k = 0; k < periods; ++k) {
      const bool collect = !classes.empty() && static_cast<std::size_t>(classes[k]) == chosen;
      const bench::StepClass c = replay.step([collect](app::DriveNode& node, const hal::SensorSample& sample,
                                                       const app::NodeInputs& in) -> const app::NodeStep& {
        if (collect) CALLGRIND_TOGGLE_COLLECT;
        const app::NodeStep& out = node.step(&sample, in);
        if (collect) CALLGRIND_TOGGLE_COLLECT;
        return out;
      });
      if (!classes.empty() && c != classes[k]) {
        std::fprintf(stderr, "pmsm_step_cost: the replay is not deterministic (step %llu)\n",
                     static_cast<unsigned long long>(k));
        return 2;
      }
      ++counts[static_cast<std::size_t>(c)];
      std::snprintf(label, sizeof label, "step %llu %s", static_cast<unsigned long long>(k),
                    bench::kStepClassNames[static_cast<std::size_t>(c)]);
      if (dump) {
        CALLGRIND_DUMP_STATS_AT(label);
      }
    }
    std::printf("pmsm_step_cost: %s, %llu steps:", path.filename().c_str(), static_cast<unsigned long long>(periods));
    for (std::size_t i = 0; i < counts.size(); ++i) {
      std::printf(" %s %llu", bench::kStepClassNames[i], static_cast<unsigned long long>(counts[i]));
    }
    std::printf("\n");
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "pmsm_step_cost: %s\n", e.what());
    return 2;
  }
}
