// `pp5echo config`: prints the configuration reference or the effective settings.
#include <iostream>
#include <memory>

#include "app/commands.hpp"
#include "app/run_setup.hpp"
#include "app/settings.hpp"

namespace pp5::app {

void addConfigCommand(CLI::App& app, int& exitCode) {
  struct Opts {
    bool markdown = false;
    std::string file;
    std::vector<std::string> overrides;
  };
  auto opts = std::make_shared<Opts>();
  auto* cmd = app.add_subcommand("config", "Print every configuration option (--markdown) or the effective settings");
  cmd->add_flag("--markdown", opts->markdown, "Print docs/configuration.md's option tables");
  cmd->add_option("CONFIG", opts->file, "TOML configuration to check and print");
  cmd->add_option("--set", opts->overrides, "Override an option: key=value (repeatable)");
  cmd->callback([opts, &exitCode] {
    logToStderr();
    Settings s;
    ConfigSchema schema;
    registerAll(schema, s);
    loadSettings(schema, opts->file, opts->overrides);
    // What `run` would refuse before it starts, `config` refuses too.
    if (!opts->markdown) checkSettings(s);
    std::cout << (opts->markdown ? schema.markdown() : schema.toToml());
    exitCode = 0;
  });
}

}  // namespace pp5::app
