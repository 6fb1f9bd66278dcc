// pmsm-thermald's control thread allocates nothing: DriveLoop::run() on its own thread,
// against the plant node on the in-process bus, through start-up, the ADC offset calibration,
// an Rs0 calibration by command, injection events with published estimates, and every
// publication pushed to the ring. Every allocator is counted (tests/support/alloc_counter.hpp:
// malloc and its family, so every operator new too), on the loop's thread only (the plant,
// the bus and the publishing thread are not the daemon's control thread).
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cstdlib>
#include <thread>

#include "alloc_counter.hpp"
#include "daemon_config.hpp"
#include "drive_loop.hpp"
#include "pmsm/hal/codec.hpp"
#include "pmsm/hal/protocol_filters.hpp"
#include "pmsm/hal/sim_bus.hpp"
#include "process/plant_node.hpp"
#include "scenario.hpp"

namespace pmsm::daemon {
namespace {

using namespace std::chrono_literals;
namespace protocol = hal::protocol;

// (The counter itself is tested in drive_alloc_test: malloc, every operator new, Eigen, libc.)
TEST(DaemonAlloc, TheControlThreadAllocatesNothing) {
  if (!test::allocation_counter_active()) {
    GTEST_SKIP() << "AddressSanitizer owns malloc: no allocation counter in this build";
  }
  const app::Scenario scenario =
      app::load_scenario(std::filesystem::path(PMSM_SOURCE_DIR) / "tests/integration/data/heatup-short.toml");
  DaemonConfig config;
  config.controller = scenario.controller;
  config.controller.drive.injection.interval_s = 0.3;
  config.supervisor = app::default_supervisor_config(config.controller);
  config.supervisor.command_timeout_s = 5.0;
  config.can.node = 1;
  config.can.sample_timeout_ms = 50.0;

  hal::SimBus bus;
  auto plant_bus = bus.connect({.fd = true, .queue_capacity = 1024});
  const protocol::FilterSet plant_filters = protocol::receive_filters(protocol::Role::kPlant, 1);
  ASSERT_TRUE(plant_bus->set_filters(plant_filters.view()).ok());
  auto rt_bus = bus.connect({.fd = true, .queue_capacity = 1024});
  const protocol::FilterSet daemon_filters = protocol::receive_filters(protocol::Role::kDaemon, 1);
  ASSERT_TRUE(rt_bus->set_filters(daemon_filters.view()).ok());
  auto supervisor = bus.connect({.fd = false, .queue_capacity = 16});
  ASSERT_TRUE(supervisor->set_filters({}).ok());

  PublicationRing ring;
  DriveLoop loop(config, *rt_bus, ring);
  plant::PlantNodeOptions options;
  options.node = 1;
  options.duration_s = 5.0;
  plant::PlantNode plant(scenario.plant, *plant_bus, options);

  std::atomic<bool> stop{false};
  std::atomic<bool> plant_done{false};
  long loop_allocations = -1;
  std::thread daemon_thread([&] {
    const long before = test::thread_allocations();  // from here on, this thread is the control loop
    loop.run(stop);
    loop_allocations = test::thread_allocations() - before;
  });
  // The supervisor: enable, calibrate at 25 C, keep the commands fresh; drain the ring. The
  // first commands go out before the plant runs: the wall-clock pace of this thread must not
  // decide when, in the plant's simulated time, the drive starts (on a loaded machine the
  // lockstep plant can run seconds ahead of a late first command, and the run then ends with
  // fewer estimates).
  protocol::CommandSender sender(1);
  hal::CanFrame frame{};
  protocol::DriveCommand run;
  run.enable = true;
  run.mode = protocol::DriveMode::kSpeed;
  run.speed_setpoint_rad_s = 94.0;
  protocol::CalibrationCommand calibrate;
  calibrate.action = protocol::CalibrationAction::kStart;
  calibrate.known_temp_C = 25.0;
  ASSERT_EQ(sender.encode(run, frame), protocol::EncodeStatus::kOk);
  ASSERT_EQ(supervisor->send(frame, 10ms), hal::SendResult::kOk);
  ASSERT_EQ(sender.encode(calibrate, frame), protocol::EncodeStatus::kOk);
  ASSERT_EQ(supervisor->send(frame, 10ms), hal::SendResult::kOk);
  std::this_thread::sleep_for(50ms);
  std::thread plant_thread([&] {
    plant.run(stop);
    plant_done = true;
  });
  std::size_t thermal = 0, estimates = 0, injections = 0;
  PublicationRecord record;
  auto count = [&](const PublicationRecord& r) {
    thermal += r.publications.thermal ? 1U : 0U;
    estimates += r.publications.resistance ? 1U : 0U;
    injections += r.publications.injection ? 1U : 0U;
  };
  const auto until = std::chrono::steady_clock::now() + 300s;
  while (!plant_done && std::chrono::steady_clock::now() < until) {
    ASSERT_EQ(sender.encode(run, frame), protocol::EncodeStatus::kOk);
    ASSERT_EQ(supervisor->send(frame, 10ms), hal::SendResult::kOk);
    for (int k = 0; k < 10; ++k) {
      while (ring.try_pop(record)) {
        count(record);
      }
      std::this_thread::sleep_for(5ms);
    }
  }
  stop = true;
  daemon_thread.join();
  plant_thread.join();
  while (ring.try_pop(record)) {
    count(record);  // the run's last publications count too
  }
  // The run exercised what it claims to.
  const LoopStats s = loop.stats();
  EXPECT_TRUE(plant_done);
  EXPECT_GE(s.samples, 50000U);
  EXPECT_EQ(s.commands_accepted[2], 1U) << "the calibration command";
  EXPECT_TRUE(loop.node().controller().telemetry().calibrated);
  EXPECT_GT(injections, 10U);
  EXPECT_GT(estimates, 3U);
  EXPECT_GE(thermal, 40U);
  EXPECT_GT(test::total_allocations(), 0) << "the counter works";
  EXPECT_EQ(loop_allocations, 0) << "allocations on the control thread";
}

}  // namespace
}  // namespace pmsm::daemon
