// libFuzzer targets: every TOML loader a user or an operator feeds — the plant configuration
// (pmsm-plant --config), the daemon configuration with its controller sections
// (pmsm-thermald --config), scenarios with their [plant] and [controller] tables
// (pmsm-thermal simulate), and the calibration and thermal-state files the drive stores.
// One source, one executable per loader (PMSM_FUZZ_LOADER).
//
// The documented failure of each is one exception type whose message names the file (and the
// line and key where there is one); anything else escaping, a crash or undefined behaviour
// (ASan + UBSan) is a finding. An empty message is a finding too.
#include <unistd.h>

#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>

#include "config_schema.hpp"

#if PMSM_FUZZ_LOADER == 1
#include "pmsm/plant/config.hpp"
#elif PMSM_FUZZ_LOADER == 2
#include "daemon_config.hpp"
#elif PMSM_FUZZ_LOADER == 3
#include "calibration_file.hpp"
#include "scenario.hpp"
#elif PMSM_FUZZ_LOADER == 4
#include "calibration_file.hpp"
#endif

namespace {

// A scratch directory of this process: loaders resolve relative paths against the file's
// own directory, and the stored-file readers take a path.
const std::filesystem::path& scratch() {
  // On the heap and never freed: still there when the atexit handler runs.
  static const std::filesystem::path* const dir = [] {
    auto* d = new std::filesystem::path(std::filesystem::temp_directory_path() /
                                        ("pmsm-fuzz-" + std::to_string(::getpid())));
    std::filesystem::create_directories(*d);
    std::atexit([] {  // libFuzzer ends with exit(): leave no directory behind
      std::error_code ec;
      std::filesystem::remove_all(scratch(), ec);
    });
    return d;
  }();
  return *dir;
}

void expect_message(const std::exception& e) {
  if (std::strlen(e.what()) == 0) std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
#if PMSM_FUZZ_LOADER == 1
  try {
    (void)pmsm::plant::parse_plant_config(text, "fuzz.toml", scratch());
  } catch (const pmsm::common::ConfigError& e) {
    expect_message(e);
  }
#elif PMSM_FUZZ_LOADER == 2
  try {
    (void)pmsm::daemon::parse_daemon_config(text, scratch() / "daemon.toml");
  } catch (const pmsm::common::ConfigError& e) {
    expect_message(e);
  }
#elif PMSM_FUZZ_LOADER == 3
  try {
    (void)pmsm::app::parse_scenario(text, scratch() / "scenario.toml");
  } catch (const pmsm::common::ConfigError& e) {
    expect_message(e);
  } catch (const pmsm::app::CalibrationFileError& e) {  // a calibration file the scenario names
    expect_message(e);
  }
#elif PMSM_FUZZ_LOADER == 4
  const std::filesystem::path file = scratch() / "stored.toml";
  {
    std::ofstream out(file, std::ios::binary | std::ios::trunc);
    out.write(text.data(), static_cast<std::streamsize>(text.size()));
  }
  try {
    (void)pmsm::app::read_calibration_file(file);
  } catch (const pmsm::app::CalibrationFileError& e) {
    expect_message(e);
  }
  try {
    (void)pmsm::app::read_thermal_state_file(file);
  } catch (const pmsm::app::CalibrationFileError& e) {
    expect_message(e);
  }
#else
#error "PMSM_FUZZ_LOADER: 1 plant, 2 daemon, 3 scenario, 4 stored files"
#endif
  return 0;
}
