// `pmsm-thermal dbc`: the DBC of one node's frames (CAN ID = base + node), generated from the
// protocol definition the daemon is built from. The package ships node 0's
// (share/pmsm-thermal/pmsm-thermal.dbc); an axis on another node needs its own for candump
// tools and `pmsm-thermal decode`.
//
//   pmsm-thermal dbc --node 2 -o axis2.dbc
//   candump can0 | pmsm-thermal decode --dbc axis2.dbc
//
// Exit status: 0; 1 when the file cannot be written (named, with the reason; an existing file
// is replaced whole or left as it was); 2 for a bad command line (CLI11).
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <system_error>

#include "cli_validators.hpp"
#include "commands.hpp"
#include "pmsm/hal/protocol.hpp"
#include "pmsm/tools/dbc_writer.hpp"

namespace pmsm::app {
namespace {

struct DbcOptions {
  int node = 0;
  std::string output;  // empty or "-": standard output
};

// Written beside the target and renamed over it: a reader never sees half a file, and a failed
// write leaves the old one.
std::string write_replacing(const std::filesystem::path& path, const std::string& text) {
  std::filesystem::path temporary = path;
  temporary += ".tmp";
  {
    std::ofstream out(temporary, std::ios::binary | std::ios::trunc);
    if (!out) {
      return std::string("cannot create ") + temporary.string() + " (" + std::strerror(errno) + ")";
    }
    out << text;
    if (!out.flush()) {
      std::error_code ignored;
      std::filesystem::remove(temporary, ignored);
      return std::string("cannot write ") + temporary.string() + " (" + std::strerror(errno) + ")";
    }
  }
  std::error_code ec;
  std::filesystem::rename(temporary, path, ec);
  if (ec) {
    std::error_code ignored;
    std::filesystem::remove(temporary, ignored);
    return "cannot replace " + path.string() + " (" + ec.message() + ")";
  }
  return {};
}

int run_dbc(const DbcOptions& o) {
  const std::string text = hal::protocol::generate_dbc(static_cast<hal::protocol::NodeId>(o.node));
  if (o.output.empty() || o.output == "-") {
    std::fputs(text.c_str(), stdout);
    return std::fflush(stdout) == 0 ? 0 : 1;
  }
  std::error_code ec;
  if (std::filesystem::is_directory(o.output, ec)) {
    std::fprintf(stderr, "dbc: '%s' is a directory; name the file to write\n", o.output.c_str());
    return 1;
  }
  if (const std::string problem = write_replacing(o.output, text); !problem.empty()) {
    std::fprintf(stderr, "dbc: %s\n", problem.c_str());
    return 1;
  }
  return 0;
}

}  // namespace

void register_dbc_command(CLI::App& app, int& exit_code) {
  auto options = std::make_shared<DbcOptions>();
  CLI::App* cmd = app.add_subcommand(
      "dbc", "Print (or write) the DBC of one node's frames, CAN ID = base + node; the package ships node 0's");
  cmd->add_option("--node", options->node, "node id of the axis (the daemon's can.node)")
      ->check(CLI::Range(0, static_cast<int>(hal::protocol::kMaxNodeId)))
      ->capture_default_str();
  cmd->add_option("-o,--output", options->output, "file to write (replaced whole); '-' or none: standard output")
      ->check(pmsm::cli::file_name());
  cmd->callback([options, &exit_code] { exit_code = run_dbc(*options); });
}

}  // namespace pmsm::app
