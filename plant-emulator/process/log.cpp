#include "log.hpp"

#include <unistd.h>

#include <cstdlib>
#include <string_view>

#include <spdlog/pattern_formatter.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include "pmsm/hal/journal.hpp"

namespace pmsm::plant {
namespace {

// The sd-daemon(3) priority prefix: "<3>" for errors ... "<7>" for debug.
class JournalPriorityFlag final : public spdlog::custom_flag_formatter {
 public:
  void format(const spdlog::details::log_msg& msg, const std::tm& /*time*/, spdlog::memory_buf_t& dest) override {
    std::string_view prefix = "<6>";
    switch (msg.level) {
      case spdlog::level::trace:
      case spdlog::level::debug:
        prefix = "<7>";
        break;
      case spdlog::level::info:
        prefix = "<6>";
        break;
      case spdlog::level::warn:
        prefix = "<4>";
        break;
      case spdlog::level::err:
        prefix = "<3>";
        break;
      case spdlog::level::critical:
        prefix = "<2>";
        break;
      case spdlog::level::off:
      case spdlog::level::n_levels:
        break;
    }
    dest.append(prefix.data(), prefix.data() + prefix.size());
  }
  [[nodiscard]] std::unique_ptr<custom_flag_formatter> clone() const override {
    return std::make_unique<JournalPriorityFlag>();
  }
};

}  // namespace

std::shared_ptr<spdlog::logger> make_process_logger(const std::string& name, const std::string& level) {
  // color_mode::automatic colours only when stderr is a terminal that supports it.
  auto sink = std::make_shared<spdlog::sinks::stderr_color_sink_mt>(spdlog::color_mode::automatic);
  auto formatter = std::make_unique<spdlog::pattern_formatter>();
  if (hal::stderr_is_journal()) {
    formatter->add_flag<JournalPriorityFlag>('J').set_pattern("%J%v");
  } else if (::isatty(STDERR_FILENO) != 0) {
    formatter->set_pattern("[%H:%M:%S.%e] [%^%l%$] %v");
  } else {
    formatter->set_pattern("[%Y-%m-%d %H:%M:%S.%e] [" + name + "] [%l] %v");
  }
  sink->set_formatter(std::move(formatter));
  auto logger = std::make_shared<spdlog::logger>(name, std::move(sink));
  logger->set_level(spdlog::level::from_str(level));
  // Warnings and errors reach the journal at once; info lines may wait for the next flush.
  logger->flush_on(spdlog::level::info);
  spdlog::set_default_logger(logger);
  return logger;
}

}  // namespace pmsm::plant
