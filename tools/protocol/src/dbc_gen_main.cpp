// pmsm-dbc-gen: writes (or checks) the files generated from the protocol definition.
//
//   pmsm-dbc-gen                                  print the node-0 DBC on stdout
//   pmsm-dbc-gen --node 3 --dbc axis3.dbc         the DBC of another node
//   pmsm-dbc-gen --dbc can/pmsm-thermal.dbc --docs docs/protocol.md
//   pmsm-dbc-gen --check --dbc ... --docs ...     exit 1 if a file is out of date
#include <algorithm>
#include <cerrno>
#include <cstring>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <string>
#include <string_view>
#include <vector>

#include "pmsm/tools/dbc_writer.hpp"
#include "standard_output.hpp"
#include "text_file.hpp"

namespace {

constexpr std::string_view kUsage =
    "usage: pmsm-dbc-gen [--node N] [--dbc FILE] [--docs FILE] [--check] | --help | --version\n"
    "  --node N     node id 0..15 for the DBC's IDs (default 0, the committed file)\n"
    "  --dbc FILE   write the DBC to FILE (without --dbc/--docs: to stdout)\n"
    "  --docs FILE  rewrite the generated section of FILE (docs/protocol.md)\n"
    "  --check      compare instead of writing\n"
    "exit status: 0; 1 if a file differs or cannot be read or written; 2 for a bad command line\n";

bool write_file(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << text;
  return static_cast<bool>(out.flush());
}

// Writes or checks one file; returns false on a difference (check) or an error.
bool emit(const std::string& path, const std::string& wanted, bool check) {
  if (check) {
    std::string current;
    if (const std::string problem = pmsm::common::read_text_file(path, current); !problem.empty()) {
      std::cerr << "pmsm-dbc-gen: cannot check " << path << ": " << problem << "\n";
      return false;
    }
    if (current != wanted) {
      std::cerr << "pmsm-dbc-gen: " << path << " is out of date; regenerate with pmsm-dbc-gen\n";
      return false;
    }
    return true;
  }
  errno = 0;
  if (!write_file(path, wanted)) {
    std::cerr << "pmsm-dbc-gen: cannot write " << path << (errno != 0 ? std::string(" (") + std::strerror(errno) + ")" : "")
              << "\n";
    return false;
  }
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  int node = 0;
  std::string dbc_path;
  std::string docs_path;
  bool check = false;
  std::vector<std::string_view> given;  // each option once: a second would silently win
  for (int i = 1; i < argc; ++i) {
    const std::string_view arg = argv[i];
    const auto value = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::cerr << "pmsm-dbc-gen: " << arg << " needs a value\n" << kUsage;
        std::exit(2);
      }
      if (std::find(given.begin(), given.end(), arg) != given.end()) {
        std::cerr << "pmsm-dbc-gen: " << arg << " given twice\n" << kUsage;
        std::exit(2);
      }
      given.push_back(arg);
      std::string v = argv[++i];
      if (v.empty() && arg != "--node") {
        std::cerr << "pmsm-dbc-gen: " << arg << " expects a file name, got an empty one\n" << kUsage;
        std::exit(2);
      }
      return v;
    };
    if (arg == "--node") {
      const std::string text = value();
      char* end = nullptr;
      const long n = std::strtol(text.c_str(), &end, 10);
      // Digits only (strtol skipped leading blanks: ' 3' passed where '3 ' did not).
      if (text.empty() || text.find_first_not_of("0123456789") != std::string::npos || end == text.c_str() ||
          *end != '\0' || n < 0 || n > pmsm::hal::protocol::kMaxNodeId) {
        std::cerr << "pmsm-dbc-gen: --node must be 0..15, got '" << text << "'\n";
        return 2;
      }
      node = static_cast<int>(n);
    } else if (arg == "--dbc") {
      dbc_path = value();
    } else if (arg == "--docs") {
      docs_path = value();
    } else if (arg == "--check") {
      check = true;
    } else if (arg == "--help" || arg == "-h") {
      std::cout << kUsage;
      return pmsm::cli::exit_with_standard_output_checked("pmsm-dbc-gen", 0, 1);
    } else if (arg == "--version") {
      std::cout << "pmsm-dbc-gen " << PMSM_VERSION << "\n";
      return pmsm::cli::exit_with_standard_output_checked("pmsm-dbc-gen", 0, 1);
    } else {
      std::cerr << "pmsm-dbc-gen: unknown argument '" << arg << "'\n" << kUsage;
      return 2;
    }
  }

  const std::string dbc = pmsm::hal::protocol::generate_dbc(static_cast<pmsm::hal::protocol::NodeId>(node));
  if (dbc_path.empty() && docs_path.empty()) {
    if (check) {
      std::cerr << "pmsm-dbc-gen: --check compares files: give --dbc FILE, --docs FILE or both\n" << kUsage;
      return 2;
    }
    std::cout << dbc;
    // 1, as the usage says of a write that failed (a full disk).
    return pmsm::cli::exit_with_standard_output_checked("pmsm-dbc-gen", 0, 1);
  }
  bool ok = true;
  if (!dbc_path.empty()) {
    ok = emit(dbc_path, dbc, check) && ok;
  }
  if (!docs_path.empty()) {
    std::string document;
    if (const std::string problem = pmsm::common::read_text_file(docs_path, document); !problem.empty()) {
      std::cerr << "pmsm-dbc-gen: cannot read " << docs_path << ": " << problem << "\n";
      return 1;
    }
    try {
      ok = emit(docs_path, pmsm::hal::protocol::update_docs(document), check) && ok;
    } catch (const std::exception& e) {
      std::cerr << "pmsm-dbc-gen: " << docs_path << ": " << e.what() << "\n";
      return 1;
    }
  }
  return ok ? 0 : 1;
}
