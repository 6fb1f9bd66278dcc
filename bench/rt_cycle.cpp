// pmsm_rt_cycle: the control loop's deadlines at the drive's own rate on this host, natively.
//
// A control thread set up as pmsm-thermald sets up its own (memory locked and the heap kept,
// SCHED_FIFO, an optional CPU, the stack prefaulted) wakes on hal::PeriodicTimer's absolute
// deadlines every control period of the scenario (10 kHz for the reference) and runs one
// DriveNode::step on the scenario's closed loop (bench/step_replay.hpp), then the plant's step
// in place of the bus. What it cannot show is the bus: no SENSOR_SAMPLE is received and no
// INVERTER_COMMAND sent (bench/hil-latency.sh measures that round trip on vcan).
//
//   pmsm_rt_cycle SCENARIO SECONDS [--priority N] [--cpu C]   (SECONDS stepped, as many of floor)
//
// The floor is measured in the same run: one-second blocks alternate between the loop that
// steps and the same timer loop that does nothing (the host's own wake-up latency, as
// cyclictest measures it), so that both see the same host.
//
// Per period it records the wake-up lateness (wake-up minus deadline), the node step's time
// and the plant's, and reports their min / median / p99 / p99.9 / max, with
//   deadline misses   periods whose node step finished after the period's end (deadline +
//                     period): the command would have been late for the next PWM period;
//   missed periods    deadlines the timer skipped because a period overran (PeriodicTimer).
// A step's time on a shared, non-real-time host includes the host's preemptions; the
// deterministic cost of a step is bench/step-cost.sh's instruction count.
//
// Exit status: 0 (measured; misses are a figure, not a failure), 2 (bad usage or scenario).
#include <algorithm>
#include <cmath>
#include <cerrno>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>
#include <vector>

#include "pmsm/hal/rt.hpp"
#include "step_replay.hpp"

namespace {

struct Options {
  std::string scenario;
  double seconds = 0.0;
  int priority = 80;  // as the daemon's default (docs/daemon.md, rt.priority)
  int cpu = -1;
};

[[noreturn]] void usage(const char* why) {
  std::fprintf(stderr, "pmsm_rt_cycle: %s\nusage: pmsm_rt_cycle SCENARIO SECONDS [--priority 1..99|0] [--cpu N]\n",
               why);
  std::exit(2);
}

bool parse_int(const char* s, int lo, int hi, int* out) {
  char* end = nullptr;
  errno = 0;
  const long v = std::strtol(s, &end, 10);
  if (errno != 0 || end == s || *end != '\0' || v < lo || v > hi) {
    return false;
  }
  *out = static_cast<int>(v);
  return true;
}

Options parse(int argc, char** argv) {
  if (argc < 3) {
    usage("a scenario and a wall time are needed");
  }
  Options o;
  o.scenario = argv[1];
  char* end = nullptr;
  o.seconds = std::strtod(argv[2], &end);
  // Every period's figures are kept for exact percentiles: 300 s at 10 kHz is 3 million
  // periods of each kind, about 120 MB.
  if (end == argv[2] || *end != '\0' || !(o.seconds > 0.0 && o.seconds <= 300.0)) {
    usage("SECONDS (stepped; as many again of floor) must be a number in (0, 300]");
  }
  for (int k = 3; k < argc; k += 2) {
    const std::string flag = argv[k];
    if (k + 1 >= argc) {
      usage(("missing value after " + flag).c_str());
    }
    if (flag == "--priority") {
      if (!parse_int(argv[k + 1], 0, 99, &o.priority)) {
        usage("--priority must be 0 (normal scheduling) or 1..99 (SCHED_FIFO)");
      }
    } else if (flag == "--cpu") {
      if (!parse_int(argv[k + 1], 0, 4095, &o.cpu)) {
        usage("--cpu must be a CPU number");
      }
    } else {
      usage(("unknown option " + flag).c_str());
    }
  }
  return o;
}

// Percentile by rank over a sorted copy (nearest rank).
double percentile(const std::vector<std::int64_t>& sorted, double p) {
  if (sorted.empty()) {
    return 0.0;
  }
  const auto n = sorted.size();
  const auto rank = static_cast<std::size_t>(std::min<double>(static_cast<double>(n) - 1.0, p * static_cast<double>(n)));
  return static_cast<double>(sorted[rank]);
}

void report(const char* name, std::vector<std::int64_t> v) {
  std::sort(v.begin(), v.end());
  std::printf("  %-22s %8.1f %8.1f %8.1f %8.1f %9.1f\n", name, percentile(v, 0.0) * 1e-3, percentile(v, 0.5) * 1e-3,
              percentile(v, 0.99) * 1e-3, percentile(v, 0.999) * 1e-3, static_cast<double>(v.back()) * 1e-3);
}

}  // namespace

int main(int argc, char** argv) {
  const Options o = parse(argc, argv);
  try {
    pmsm::bench::StepReplay replay(o.scenario);
    const auto period = std::chrono::nanoseconds(std::llround(replay.period_s() * 1e9));
    const auto periods = std::max<std::size_t>(1, static_cast<std::size_t>(o.seconds / replay.period_s()));
    std::vector<std::int64_t> lateness;
    std::vector<std::int64_t> node_ns;
    std::vector<std::int64_t> plant_ns;
    lateness.reserve(periods);
    node_ns.reserve(periods);
    plant_ns.reserve(periods);

    // The daemon's control-thread setup (daemon/main.cpp); each refusal is said, not fatal.
    std::string setup;
    if (const pmsm::hal::Status s = pmsm::hal::prepare_memory_for_realtime(); !s.ok()) {
      std::fprintf(stderr, "pmsm_rt_cycle: memory not locked: %s\n", s.message().c_str());
      setup += "memory not locked; ";
    }
    if (o.priority > 0) {
      if (const pmsm::hal::Status s = pmsm::hal::set_realtime_priority(o.priority); !s.ok()) {
        std::fprintf(stderr, "pmsm_rt_cycle: normal scheduling: %s\n", s.message().c_str());
        setup += "SCHED_FIFO refused; ";
      } else {
        setup += "SCHED_FIFO " + std::to_string(o.priority) + "; ";
      }
    } else {
      setup += "normal scheduling; ";
    }
    if (o.cpu >= 0) {
      const int cpus[] = {o.cpu};
      if (const pmsm::hal::Status s = pmsm::hal::set_cpu_affinity(cpus); !s.ok()) {
        std::fprintf(stderr, "pmsm_rt_cycle: not pinned: %s\n", s.message().c_str());
        setup += "not pinned; ";
      } else {
        setup += "CPU " + std::to_string(o.cpu) + "; ";
      }
    }
    pmsm::hal::prefault_stack();

    // Alternating one-second blocks: even ones only wake up (the floor), odd ones step.
    const auto block = std::clamp<std::size_t>(static_cast<std::size_t>(std::round(1.0 / replay.period_s())), 1, periods);
    std::vector<std::int64_t> floor_lateness;
    floor_lateness.reserve(periods);
    std::uint64_t misses = 0;
    std::uint64_t floor_misses = 0;
    pmsm::hal::PeriodicTimer timer(period);
    timer.start();
    for (std::size_t k = 0; k < 2 * periods; ++k) {
      const pmsm::hal::PeriodicTimer::Tick tick = timer.wait_next();
      const std::int64_t woke = pmsm::hal::monotonic_ns();
      if ((k / block) % 2 == 0) {
        floor_lateness.push_back(woke - tick.deadline_ns);
        floor_misses += woke - tick.deadline_ns > period.count() ? 1U : 0U;
        continue;
      }
      std::int64_t stepped = woke;
      replay.step([&](pmsm::app::DriveNode& node, const pmsm::hal::SensorSample& sample,
                      const pmsm::app::NodeInputs& in) -> const pmsm::app::NodeStep& {
        const pmsm::app::NodeStep& out = node.step(&sample, in);
        stepped = pmsm::hal::monotonic_ns();
        return out;
      });
      const std::int64_t done = pmsm::hal::monotonic_ns();
      lateness.push_back(woke - tick.deadline_ns);
      node_ns.push_back(stepped - woke);
      plant_ns.push_back(done - stepped);
      misses += stepped - tick.deadline_ns > period.count() ? 1U : 0U;
    }
    const pmsm::hal::PeriodicTimer::Stats st = timer.stats();
    std::printf("pmsm_rt_cycle: %s, %zu stepped periods of %.1f us beside as many of the floor, in blocks of %zu; %s\n",
                o.scenario.c_str(), lateness.size(), static_cast<double>(period.count()) * 1e-3, block, setup.c_str());
    std::printf("  %-22s %8s %8s %8s %8s %9s   (us)\n", "", "min", "median", "p99", "p99.9", "max");
    report("floor: wake-up lateness", floor_lateness);
    report("wake-up lateness", lateness);
    report("DriveNode::step", node_ns);
    report("plant step (no bus)", plant_ns);
    std::vector<std::int64_t> total(lateness.size());
    for (std::size_t k = 0; k < total.size(); ++k) {
      total[k] = lateness[k] + node_ns[k];
    }
    report("deadline to command", total);
    const auto pct = [](std::uint64_t n, std::size_t of) {
      return 100.0 * static_cast<double>(n) / static_cast<double>(std::max<std::size_t>(of, 1));
    };
    std::printf("  deadline misses (command after the period's end): %llu of %zu (%.3f %%); floor (wake-up after it): %llu of %zu (%.3f %%)\n",
                static_cast<unsigned long long>(misses), lateness.size(), pct(misses, lateness.size()),
                static_cast<unsigned long long>(floor_misses), floor_lateness.size(), pct(floor_misses, floor_lateness.size()));
    std::printf("  timer, both kinds of block: %llu wake-ups after an overrun, %llu periods skipped\n",
                static_cast<unsigned long long>(st.deadline_misses), static_cast<unsigned long long>(st.missed_periods));
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "pmsm_rt_cycle: %s\n", e.what());
    return 2;
  }
}
