// Plant-emulator speed (DESIGN §9): one step() of the plant per PWM period, on the
// reference and ideal profiles, at standstill and at speed; the truth/state snapshot used
// for the bench frames; and lockstep simulation over the in-process bus (PlantNode on one
// thread, a stand-in controller on another: the process's own overhead without a kernel).
//
// "sim_s_per_wall_s" is simulated seconds per wall-clock second (> 1: faster than real time).
#include <benchmark/benchmark.h>

#include <atomic>
#include <filesystem>
#include <optional>
#include <string>
#include <thread>

#include "pmsm/hal/codec.hpp"
#include "pmsm/hal/protocol_filters.hpp"
#include "pmsm/hal/sim_bus.hpp"
#include "pmsm/plant/plant.hpp"
#include "process/plant_node.hpp"

namespace {

using namespace std::chrono_literals;
namespace plant = pmsm::plant;
namespace hal = pmsm::hal;
namespace protocol = pmsm::hal::protocol;

plant::PlantConfig profile(const char* name) {
  return plant::load_plant_config(std::filesystem::path(PMSM_SOURCE_DIR) / "plant-emulator/profiles" / name);
}

// A fixed voltage vector (v_a = +10 V, v_b = v_c = -5 V at 650 V): current flows, the
// inverter model's dead time and drop are exercised.
hal::InverterCommand dc_vector_command() {
  hal::InverterCommand c;
  c.enable = true;
  c.duty = {static_cast<std::uint16_t>(0.5154 * hal::kDutyFullScale), static_cast<std::uint16_t>(0.4923 * hal::kDutyFullScale),
            static_cast<std::uint16_t>(0.4923 * hal::kDutyFullScale)};
  return c;
}

// Arguments: profile (0 reference, 1 ideal), imposed speed in rad/s (0: standstill).
void BM_PlantStep(benchmark::State& state) {
  plant::PlantConfig config = profile(state.range(0) == 0 ? "reference.toml" : "ideal.toml");
  if (state.range(1) != 0) {
    config.load.profile = plant::LoadProfile::speed_cycle;
    config.load.speed_rad_s = static_cast<double>(state.range(1));
  }
  plant::Plant p(config);
  hal::InverterCommand command = dc_vector_command();
  for (auto _ : state) {
    command.sequence = p.sample().sequence;
    benchmark::DoNotOptimize(p.step(command));
  }
  state.SetLabel(std::string(state.range(0) == 0 ? "reference" : "ideal") +
                 (state.range(1) != 0 ? " at " + std::to_string(state.range(1)) + " rad/s" : " standstill"));
  state.counters["sim_s_per_wall_s"] =
      benchmark::Counter(p.period_s() * static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_PlantStep)->Args({0, 0})->Args({0, 150})->Args({1, 0})->Args({1, 150});

void BM_PlantTruthAndState(benchmark::State& state) {
  plant::Plant p(profile("reference.toml"));
  for (int i = 0; i < 100; ++i) {
    (void)p.step(dc_vector_command());
  }
  for (auto _ : state) {
    benchmark::DoNotOptimize(p.truth());
    benchmark::DoNotOptimize(p.state());
  }
}
BENCHMARK(BM_PlantTruthAndState);

// Lockstep through PlantNode on the in-process bus: encode, queue, wake, decode, step, both
// ways, per period. One iteration = one period.
void BM_PlantNodeLockstepSimBus(benchmark::State& state) {
  hal::SimBus bus;
  auto plant_end = bus.connect({.fd = true, .queue_capacity = 1024});
  auto controller = bus.connect({.fd = true, .queue_capacity = 1024});
  const protocol::FilterSet pf = protocol::receive_filters(protocol::Role::kPlant, 0);
  const protocol::FilterSet df = protocol::receive_filters(protocol::Role::kDaemon, 0);
  (void)plant_end->set_filters(pf.view());
  (void)controller->set_filters(df.view());
  plant::PlantNodeOptions options;
  options.mode = plant::RunMode::kLockstep;
  plant::PlantNode node(profile("reference.toml"), *plant_end, options);
  std::atomic<bool> stop{false};
  std::thread runner([&] { (void)node.run(stop); });

  protocol::DaemonReceiver receiver(0);
  hal::ReceivedFrame r;
  hal::CanFrame out;
  hal::InverterCommand command = dc_vector_command();
  std::optional<std::uint32_t> last;
  for (auto _ : state) {
    // Wait for the next new sample, answer it.
    for (;;) {
      if (controller->receive(r, 1s) != hal::ReceiveStatus::kFrame) {
        state.SkipWithError("no sample from the plant node");
        break;
      }
      const protocol::DaemonInput in = receiver.receive(r.frame, std::chrono::nanoseconds{0});
      if (const auto* s = std::get_if<hal::SensorSample>(&in); s != nullptr && (!last || s->sequence != *last)) {
        last = s->sequence;
        command.sequence = s->sequence;
        (void)protocol::encode(command, 0, out);
        (void)controller->send(out);
        break;
      }
    }
  }
  stop = true;
  runner.join();
  state.counters["sim_s_per_wall_s"] =
      benchmark::Counter(1e-4 * static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_PlantNodeLockstepSimBus)->UseRealTime();

}  // namespace
