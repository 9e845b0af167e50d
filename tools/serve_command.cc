#include <fmt/format.h>
#include <pthread.h>
#include <spdlog/spdlog.h>

#include <csignal>
#include <fstream>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "server/broker.h"
#include "server/localization_service.h"
#include "tools/commands.h"
#include "util/check.h"

namespace hscloc {
namespace {

struct ServeArguments {
  bool broker = false;
  std::string backend = "tcp://*:5556";
  std::string map_dir;
  std::string matcher = "hsc";
  std::string curve_secret_key_file;
  std::string curve_allowed_keys_file;
  ServiceOptions options;
};

// The first line of a key file, trimmed.
std::string ReadKey(const std::string& path) {
  std::ifstream file(path);
  std::string key;
  if (!file || !std::getline(file, key)) ThrowInvalidArgument("cannot read a key from {}", path);
  while (!key.empty() && std::isspace(static_cast<unsigned char>(key.back()))) key.pop_back();
  if (key.size() != 40) ThrowInvalidArgument("{}: a Z85 CURVE key has 40 characters", path);
  return key;
}

// Blocks SIGTERM, SIGINT and SIGHUP in this thread and every thread started after it, so that
// WaitForSignal takes them synchronously.
sigset_t BlockSignals() {
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGHUP);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  return signals;
}

int RunBroker(const ServeArguments& arguments) {
  BrokerOptions options;
  options.front = arguments.options.bind;
  options.back = arguments.backend;
  options.max_queue = arguments.options.max_queue;
  sigset_t signals = BlockSignals();
  Broker broker(options);
  const auto [front, back] = broker.Start();
  std::cout << fmt::format("broker listening on {} (clients) and {} (workers)\n", front, back)
            << std::flush;
  while (true) {
    int signal = 0;
    if (sigwait(&signals, &signal) != 0 || signal == SIGHUP) continue;
    broker.Stop();
    spdlog::info("broker stopped: {} workers dropped, {} requests retried",
                 broker.workers_dropped(), broker.requests_retried());
    return 0;
  }
}

int RunServe(ServeArguments& arguments) {
  if (arguments.broker) return RunBroker(arguments);
  ServiceOptions& options = arguments.options;
  if (arguments.map_dir.empty()) ThrowInvalidArgument("serve: --map is required (except --broker)");
  options.localizer.matcher = ParseMatcher(arguments.matcher);
  if (!arguments.curve_secret_key_file.empty()) {
    options.curve_secret_key = ReadKey(arguments.curve_secret_key_file);
  }
  if (!arguments.curve_allowed_keys_file.empty()) {
    std::ifstream file(arguments.curve_allowed_keys_file);
    if (!file) ThrowInvalidArgument("cannot read {}", arguments.curve_allowed_keys_file);
    for (std::string line; std::getline(file, line);) {
      if (line.empty() || line[0] == '#') continue;
      if (line.size() < 40) {
        ThrowInvalidArgument("{}: '{}' is no Z85 key", arguments.curve_allowed_keys_file, line);
      }
      options.curve_allowed_client_keys.push_back(line.substr(0, 40));
    }
  }
  // Queries run in parallel on the workers, each on one core (docs/decisions.md).
  SetComputeThreads(1);

  sigset_t signals = BlockSignals();

  LocalizationService service(arguments.map_dir, options);
  const std::string endpoint = service.Start();
  std::cout << fmt::format("listening on {}\n", endpoint) << std::flush;
  while (true) {
    int signal = 0;
    if (sigwait(&signals, &signal) != 0) continue;
    if (signal == SIGHUP) {
      spdlog::info("SIGHUP: reloading {}", arguments.map_dir);
      service.Reload();
      continue;
    }
    spdlog::info("{}: draining in-flight requests", signal == SIGTERM ? "SIGTERM" : "SIGINT");
    service.Stop();
    return 0;
  }
}

}  // namespace

void AddServeCommand(CLI::App& app, CommandRunner& run) {
  auto arguments = std::make_shared<ServeArguments>();
  ServiceOptions& options = arguments->options;
  CLI::App* command = app.add_subcommand("serve", "Serve localization requests over ZeroMQ");
  command->add_option("--map", arguments->map_dir, "Trained map bundle")
      ->check(CLI::ExistingDirectory);
  command->add_option("--bind", options.bind, "ZeroMQ endpoint for clients (port 0: any free port)")
      ->capture_default_str();
  command->add_flag("--broker", arguments->broker,
                    "Run as the broker: clients on --bind, workers on --backend");
  command->add_option("--backend", arguments->backend, "The broker's endpoint for workers")
      ->capture_default_str();
  command->add_option("--connect", options.connect,
                      "Work for the broker at this endpoint instead of binding");
  command->add_option("--workers", options.workers, "Worker threads (0: one per core)")
      ->capture_default_str();
  command
      ->add_option("--max-queue", options.max_queue,
                   "Waiting requests beyond which OVERLOADED is answered")
      ->capture_default_str();
  command
      ->add_option("--max-message-bytes", options.max_message_bytes,
                   "Larger messages are dropped by ZeroMQ")
      ->capture_default_str();
  command->add_option("--max-keypoints", options.limits.max_keypoints, "Keypoints per request")
      ->capture_default_str();
  command->add_option("--matcher", arguments->matcher, "hsc (the network) or nn (baseline)")
      ->check(CLI::IsMember({"hsc", "nn"}))
      ->capture_default_str();
  command->add_option("--top-k", options.localizer.top_k, "Retrieved images per query")
      ->capture_default_str();
  command->add_option("--curve-secret-key", arguments->curve_secret_key_file,
                      "File with the server's CURVE secret key (hscloc keygen): encrypts "
                      "traffic and authenticates clients");
  command->add_option("--curve-allowed-keys", arguments->curve_allowed_keys_file,
                      "File with the allowed clients' public keys, one per line");
  command->callback([&run, arguments] { run = [arguments] { return RunServe(*arguments); }; });
}

void AddKeygenCommand(CLI::App& app, CommandRunner& run) {
  auto prefix = std::make_shared<std::string>();
  CLI::App* command =
      app.add_subcommand("keygen", "Generate a CURVE key pair: PREFIX.key (secret), PREFIX.pub");
  command->add_option("--out", *prefix, "Path prefix of the two key files")->required();
  command->callback([&run, prefix] {
    run = [prefix] {
      const CurveKeyPair keys = GenerateCurveKeyPair();
      {
        std::ofstream secret(*prefix + ".key");
        secret << keys.secret_key << '\n';
        if (!secret) ThrowInvalidArgument("cannot write {}.key", *prefix);
      }
      std::filesystem::permissions(*prefix + ".key", std::filesystem::perms::owner_read |
                                                         std::filesystem::perms::owner_write);
      std::ofstream(*prefix + ".pub") << keys.public_key << '\n';
      std::cout << fmt::format("public key {} written to {}.pub, secret key to {}.key\n",
                               keys.public_key, *prefix, *prefix);
      return 0;
    };
  });
}

}  // namespace hscloc
