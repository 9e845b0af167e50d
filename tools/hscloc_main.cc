// hscloc: the map builder's and operator's command line. It only parses options and wires the
// libraries together; every algorithm lives in the layer libraries.
#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <cstdio>
#include <functional>
#include <stdexcept>
#include <string>
#include <vector>

#include "tools/commands.h"
#include "util/logging.h"

int main(int argc, char** argv) {
  CLI::App app{
      "hscloc: city-scale visual localization (hierarchical scene coordinate classification)"};
  app.require_subcommand(1);
  // --log-level works on either side of the subcommand (`train ... --log-level warn`): what a
  // subcommand does not know falls through to the tool. Subcommands inherit this when added.
  app.fallthrough();
  std::string log_level = "info";
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error or off")
      ->capture_default_str();
  app.set_version_flag("--version", "hscloc 0.1.0");

  hscloc::CommandRunner run;
  hscloc::AddSynthCommand(app, run);
  hscloc::AddExtractCommand(app, run);
  hscloc::AddTriangulateCommand(app, run);
  hscloc::AddBankCommand(app, run);
  hscloc::AddBuildMapCommand(app, run);
  hscloc::AddInspectCommand(app, run);
  hscloc::AddTrainCommand(app, run);
  hscloc::AddLocalizeCommand(app, run);
  hscloc::AddEvalCommand(app, run);
  hscloc::AddPipelineCommand(app, run);
  hscloc::AddServeCommand(app, run);
  hscloc::AddKeygenCommand(app, run);
  hscloc::AddDemoCommand(app, run);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& error) {
    return app.exit(error);
  }
  try {
    hscloc::SetupLogging(log_level);
    return run();
  } catch (const std::invalid_argument& error) {
    std::fprintf(stderr, "error: %s\n", error.what());
    return 2;
  } catch (const std::exception& error) {
    std::fprintf(stderr, "failed: %s\n", error.what());
    return 1;
  }
}
