// The control step in Google Benchmark, by step class: DriveNode::step (the daemon's whole
// per-sample path: front end, supervisor, controller, publications) on the replay of
// bench/scenarios/step-cost.toml (4 simulated seconds, every kind of step; bench/step_replay.hpp
// says how a step is classed). Only the step is timed (manual time, one steady_clock pair per
// step, which adds its own ~20-40 ns); the plant between steps is not.
//
//   build/release/bench/pmsm_speed_bench --benchmark_filter=DriveNodeStep
//
// Counters per class: mean and largest time per step in ns (the `_max` of a class is one
// step's time on a shared machine: read it as an order of magnitude; the deterministic
// worst case is bench/step-cost.sh's instruction count).
#include <benchmark/benchmark.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <string>

#include "step_replay.hpp"

namespace {

using pmsm::bench::kStepClassCount;
using pmsm::bench::kStepClassNames;

constexpr std::int64_t kReplaySteps = 40000;

void BM_DriveNodeStepByClass(benchmark::State& state) {
  pmsm::bench::StepReplay replay(std::string(PMSM_SOURCE_DIR) + "/bench/scenarios/step-cost.toml");
  std::array<double, kStepClassCount> sum_ns{};
  std::array<double, kStepClassCount> max_ns{};
  std::array<std::int64_t, kStepClassCount> steps{};
  for (auto _ : state) {
    std::int64_t took_ns = 0;
    const pmsm::bench::StepClass c =
        replay.step([&](pmsm::app::DriveNode& node, const pmsm::hal::SensorSample& sample,
                        const pmsm::app::NodeInputs& in) -> const pmsm::app::NodeStep& {
          const auto t0 = std::chrono::steady_clock::now();
          const pmsm::app::NodeStep& out = node.step(&sample, in);
          took_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - t0).count();
          return out;
        });
    state.SetIterationTime(static_cast<double>(took_ns) * 1e-9);
    const auto i = static_cast<std::size_t>(c);
    sum_ns[i] += static_cast<double>(took_ns);
    max_ns[i] = std::max(max_ns[i], static_cast<double>(took_ns));
    ++steps[i];
  }
  for (std::size_t i = 0; i < kStepClassCount; ++i) {
    if (steps[i] > 0) {
      state.counters[std::string(kStepClassNames[i]) + "_ns"] = sum_ns[i] / static_cast<double>(steps[i]);
      state.counters[std::string(kStepClassNames[i]) + "_max_ns"] = max_ns[i];
      state.counters[std::string(kStepClassNames[i]) + "_steps"] = static_cast<double>(steps[i]);
    }
  }
}
BENCHMARK(BM_DriveNodeStepByClass)->UseManualTime()->Iterations(kReplaySteps)->Repetitions(5)->Unit(benchmark::kNanosecond);

}  // namespace
