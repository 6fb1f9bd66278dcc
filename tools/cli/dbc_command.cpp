// `pmsm-thermal dbc`: the DBC of one node's frames (CAN ID = base + node), generated from the
// protocol definition the daemon is built from. The package ships node 0's
// (share/pmsm-thermal/pmsm-thermal.dbc); an axis on another node needs its own for candump
// tools and `pmsm-thermal decode`.
//
//   pmsm-thermal dbc --node 2 -o axis2.dbc
//   candump can0 | pmsm-thermal decode --dbc axis2.dbc
//
// Exit status: 0; 2 for a bad command line (CLI11: a node outside 0..15, an empty file name);
// 3 when the DBC could not be written (the file or standard output, named with the reason), as
// `simulate` says of its outputs. The file is written in place, as a shell's `>` would: a
// symbolic link is followed, a directory is refused.
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
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

constexpr int kExitOutput = 3;

int run_dbc(const DbcOptions& o) {
  const std::string text = hal::protocol::generate_dbc(static_cast<hal::protocol::NodeId>(o.node));
  const bool to_stdout = o.output.empty() || o.output == "-";
  const std::string name = to_stdout ? std::string("standard output") : "'" + o.output + "'";
  std::error_code ec;
  if (!to_stdout && std::filesystem::is_directory(o.output, ec)) {
    std::fprintf(stderr, "dbc: %s is a directory; name the file to write\n", name.c_str());
    return kExitOutput;
  }
  std::FILE* file = to_stdout ? stdout : std::fopen(o.output.c_str(), "wb");
  if (file == nullptr) {
    std::fprintf(stderr, "dbc: cannot create %s (%s)\n", name.c_str(), std::strerror(errno));
    return kExitOutput;
  }
  errno = 0;
  bool ok = std::fputs(text.c_str(), file) >= 0 && std::fflush(file) == 0 && std::ferror(file) == 0;
  int error = errno;
  if (!to_stdout && std::fclose(file) != 0) {
    ok = false;
    error = error != 0 ? error : errno;
  }
  if (!ok) {
    std::fprintf(stderr, "dbc: cannot write %s (%s)\n", name.c_str(), std::strerror(error != 0 ? error : EIO));
    return kExitOutput;
  }
  return 0;
}

}  // namespace

void register_dbc_command(CLI::App& app, int& exit_code) {
  auto options = std::make_shared<DbcOptions>();
  CLI::App* cmd = app.add_subcommand(
      "dbc", "Print (or write) the DBC of one node's frames, CAN ID = base + node; the package ships node 0's");
  cmd->add_option("--node", options->node, "node id of the axis (the daemon's can.node)")
      ->check(pmsm::cli::integer_in_range(0, static_cast<long long>(hal::protocol::kMaxNodeId)))
      ->capture_default_str();
  cmd->add_option("-o,--output", options->output, "file to write; '-' or none: standard output")
      ->check(pmsm::cli::file_name());
  cmd->callback([options, &exit_code] { exit_code = run_dbc(*options); });
}

}  // namespace pmsm::app
