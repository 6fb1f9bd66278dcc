// pmsm-thermal: the project's command-line tool (planning, simulation, bus decoding).
#include <CLI/CLI.hpp>

#include <cstdio>
#include <exception>
#include <new>
#include <string>

#include "cli_validators.hpp"
#include "standard_output.hpp"
#include "commands.hpp"

int main(int argc, char** argv) {
  CLI::App app{"pmsm-thermal: planning, simulation, bus and analysis tools for the pmsm-thermal drive"};
  app.require_subcommand(1);
  app.set_version_flag("--version", std::string("pmsm-thermal ") + PMSM_VERSION);
  int exit_code = 0;
  pmsm::app::register_budget_command(app, exit_code);
  pmsm::app::register_losses_command(app, exit_code);
  pmsm::app::register_simulate_command(app, exit_code);
  pmsm::app::register_config_keys_command(app, exit_code);
  pmsm::app::register_decode_command(app, exit_code);
  pmsm::app::register_command_command(app, exit_code);
  pmsm::app::register_monitor_command(app, exit_code);
  pmsm::app::register_dbc_command(app, exit_code);
  // A first word that is no command: say so and list them (CLI11 says only "A subcommand is
  // required").
  if (argc > 1 && argv[1][0] != '-') {
    std::string names;
    bool known = false;
    for (const CLI::App* sub : app.get_subcommands({})) {
      names += (names.empty() ? "" : ", ") + sub->get_name();
      known = known || sub->get_name() == argv[1];
    }
    if (!known) {
      std::fprintf(stderr, "pmsm-thermal: '%s' is not a command; the commands are %s (--help for more)\n", argv[1],
                   names.c_str());
      return 2;
    }
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help and --version exit 0; a bad command line is unusable input (2), as a bad file is,
    // not one of CLI11's own codes.
    return pmsm::cli::exit_on_parse_error(app, e, 2, "pmsm-thermal", 3);
  } catch (const std::bad_alloc&) {
    // (Each command bounds what it reads; this is the last line of defence, not an abort.) 2:
    // the command could not do its work, never a check's 1 (monitor's gate, decode --strict).
    std::fprintf(stderr, "pmsm-thermal: out of memory\n");
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "pmsm-thermal: %s\n", e.what());
    return 2;
  }
  // 3, as for any output that could not be written (simulate's CSV, dbc's file): a report, a
  // table or a decoded log piped to a full disk is not a success.
  return pmsm::cli::exit_with_standard_output_checked("pmsm-thermal", exit_code, 3);
}
