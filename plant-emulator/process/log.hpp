// Logging for the pmsm-plant process: spdlog to stderr, as journald expects it from a
// service (DESIGN §7): colours only on a terminal; where stderr is the journal's stream (hal::stderr_is_journal) no
// timestamps of our own (the journal stamps every line) and the sd-daemon "<N>" priority
// prefix, so `journalctl -p warning` filters by level.
#pragma once

#include <memory>
#include <string>

#include <spdlog/logger.h>

namespace pmsm::plant {

// Creates the process logger (also made the spdlog default). `level`: trace, debug, info,
// warn, error, critical or off.
std::shared_ptr<spdlog::logger> make_process_logger(const std::string& name, const std::string& level);

}  // namespace pmsm::plant
