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
//   deadline misses   deadlines whose command (the end of the node step) came after the
//                     period's end (deadline + period), late for the next PWM period, plus
//                     the deadlines the timer skipped after an overrun (no command at all);
//                     the floor's are counted alike, from its wake-ups.
// The node step's time is DriveNode::step alone; "deadline to command" also holds the
// replay's own work before it (the scenario's set-points), as a daemon's frame handling.
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
    if (flag.rfind("--", 0) != 0) {
      usage(("unexpected argument " + flag).c_str());
    }
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

// Percentile of a sorted series by nearest rank: the smallest value with at least p n values
// at or below it (p = 0: the minimum).
double percentile(const std::vector<std::int64_t>& sorted, double p) {
  if (sorted.empty()) {
    return 0.0;
  }
  const double n = static_cast<double>(sorted.size());
  const double rank = std::clamp(std::ceil(p * n), 1.0, n);
  return static_cast<double>(sorted[static_cast<std::size_t>(rank) - 1]);
}

void report(const char* name, std::vector<std::int64_t> v) {
  if (v.empty()) {
    std::printf("  %-22s (none)\n", name);
    return;
  }
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
    const auto periods = static_cast<std::size_t>(std::max<long long>(1, std::llround(o.seconds / replay.period_s())));
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

    // Alternating one-second blocks: even ones only wake up (the floor), odd ones step, until
    // each kind has its count of wake-ups. A deadline the timer skipped after an overrun is a
    // miss of the kind whose block it fell in: no command went out for it.
    const auto block = std::clamp<std::size_t>(static_cast<std::size_t>(std::round(1.0 / replay.period_s())), 1, periods);
    std::vector<std::int64_t> floor_lateness;
    std::vector<std::int64_t> to_command;
    floor_lateness.reserve(periods);
    to_command.reserve(periods);
    std::uint64_t late = 0;
    std::uint64_t skipped = 0;
    std::uint64_t floor_late = 0;
    std::uint64_t floor_skipped = 0;
    pmsm::hal::PeriodicTimer timer(period);
    timer.start();
    for (std::size_t k = 0; lateness.size() < periods || floor_lateness.size() < periods; ++k) {
      const pmsm::hal::PeriodicTimer::Tick tick = timer.wait_next();
      const std::int64_t woke = pmsm::hal::monotonic_ns();
      const bool floor_turn =
          lateness.size() >= periods || (floor_lateness.size() < periods && (k / block) % 2 == 0);
      if (floor_turn) {
        floor_lateness.push_back(woke - tick.deadline_ns);
        floor_late += woke - tick.deadline_ns > period.count() ? 1U : 0U;
        floor_skipped += tick.missed_periods;
        continue;
      }
      std::int64_t entered = woke;
      std::int64_t stepped = woke;
      replay.step([&](pmsm::app::DriveNode& node, const pmsm::hal::SensorSample& sample,
                      const pmsm::app::NodeInputs& in) -> const pmsm::app::NodeStep& {
        entered = pmsm::hal::monotonic_ns();
        const pmsm::app::NodeStep& out = node.step(&sample, in);
        stepped = pmsm::hal::monotonic_ns();
        return out;
      });
      const std::int64_t done = pmsm::hal::monotonic_ns();
      lateness.push_back(woke - tick.deadline_ns);
      node_ns.push_back(stepped - entered);
      plant_ns.push_back(done - stepped);
      to_command.push_back(stepped - tick.deadline_ns);
      late += stepped - tick.deadline_ns > period.count() ? 1U : 0U;
      skipped += tick.missed_periods;
    }
    std::printf("pmsm_rt_cycle: %s, %zu stepped periods of %.1f us beside as many of the floor, in blocks of %zu; %s\n",
                o.scenario.c_str(), lateness.size(), static_cast<double>(period.count()) * 1e-3, block, setup.c_str());
    std::printf("  %-22s %8s %8s %8s %8s %9s   (us)\n", "", "min", "median", "p99", "p99.9", "max");
    report("floor: wake-up lateness", floor_lateness);
    report("wake-up lateness", lateness);
    report("DriveNode::step", node_ns);
    report("plant step (no bus)", plant_ns);
    report("deadline to command", to_command);
    const auto pct = [](std::uint64_t n, std::uint64_t of) {
      return 100.0 * static_cast<double>(n) / static_cast<double>(std::max<std::uint64_t>(of, 1));
    };
    const std::uint64_t deadlines = lateness.size() + skipped;
    const std::uint64_t floor_deadlines = floor_lateness.size() + floor_skipped;
    std::printf("  deadline misses: %llu of %llu deadlines (%.3f %%): %llu commands after the period's end, %llu periods skipped\n",
                static_cast<unsigned long long>(late + skipped), static_cast<unsigned long long>(deadlines),
                pct(late + skipped, deadlines), static_cast<unsigned long long>(late),
                static_cast<unsigned long long>(skipped));
    std::printf("  floor: %llu of %llu deadlines (%.3f %%): %llu wake-ups after the period's end, %llu periods skipped\n",
                static_cast<unsigned long long>(floor_late + floor_skipped), static_cast<unsigned long long>(floor_deadlines),
                pct(floor_late + floor_skipped, floor_deadlines), static_cast<unsigned long long>(floor_late),
                static_cast<unsigned long long>(floor_skipped));
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "pmsm_rt_cycle: %s\n", e.what());
    return 2;
  }
}
