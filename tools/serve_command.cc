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
  std::string matcher = "auto";
  std::string retrieval = RetrievalModeName(LocalizerOptions().retrieval);
  // Key files (hscloc keygen): secret keys hold one key, lists one public key per line.
  std::string curve_secret_key_file;
  std::string curve_allowed_keys_file;
  std::string curve_admin_keys_file;
  std::string curve_server_key_file;
  std::string backend_curve_secret_key_file;
  std::string curve_allowed_worker_keys_file;
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

// The public keys of a list file, one per line ('#' starts a comment line); none for no file.
std::vector<std::string> ReadKeyList(const std::string& path) {
  std::vector<std::string> keys;
  if (path.empty()) return keys;
  std::ifstream file(path);
  if (!file) ThrowInvalidArgument("cannot read {}", path);
  for (std::string line; std::getline(file, line);) {
    if (line.empty() || line[0] == '#') continue;
    if (line.size() < 40) ThrowInvalidArgument("{}: '{}' is no Z85 key", path, line);
    keys.push_back(line.substr(0, 40));
  }
  return keys;
}

std::string ReadOptionalKey(const std::string& path) { return path.empty() ? "" : ReadKey(path); }

// Flags that the chosen mode cannot honour are refused here, before anything starts: a security
// flag silently ignored would leave the service open while its operator believes it closed.
void CheckFlagsFitMode(const ServeArguments& arguments) {
  const auto refuse = [](bool given, const std::string& flag, const std::string& why) {
    if (given) ThrowInvalidArgument("serve: {} {}", flag, why);
  };
  if (arguments.broker) {
    refuse(!arguments.map_dir.empty(), "--map",
           "is not used by a broker (--broker): workers load it");
    refuse(!arguments.options.connect.empty(), "--connect", "and --broker exclude each other");
    refuse(!arguments.curve_admin_keys_file.empty(), "--curve-admin-keys",
           "cannot be honoured by a broker: it holds no map; reload each worker on its admin "
           "endpoint");
    refuse(!arguments.curve_server_key_file.empty(), "--curve-server-key",
           "is for workers (--connect): the broker's back takes --backend-curve-secret-key");
    return;
  }
  for (const auto& [file, flag] :
       {std::pair{arguments.backend_curve_secret_key_file, "--backend-curve-secret-key"},
        std::pair{arguments.curve_allowed_worker_keys_file, "--curve-allowed-worker-keys"}}) {
    refuse(!file.empty(), flag, "is for the broker (--broker) only");
  }
  if (arguments.map_dir.empty()) ThrowInvalidArgument("serve: --map is required (except --broker)");
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
  options.admin_bind = arguments.options.admin_bind;
  options.metrics_bind = arguments.options.metrics_bind;
  options.max_queue = arguments.options.max_queue;
  options.curve_secret_key = ReadOptionalKey(arguments.curve_secret_key_file);
  options.curve_allowed_client_keys = ReadKeyList(arguments.curve_allowed_keys_file);
  options.backend_curve_secret_key = ReadOptionalKey(arguments.backend_curve_secret_key_file);
  options.curve_allowed_worker_keys = ReadKeyList(arguments.curve_allowed_worker_keys_file);
  sigset_t signals = BlockSignals();
  Broker broker(options);
  const auto [front, back] = broker.Start();
  std::cout << fmt::format("broker listening on {} (clients) and {} (workers)\nadmin on {}\n",
                           front, back, broker.admin_endpoint());
  if (!broker.metrics_url().empty()) std::cout << "metrics on " << broker.metrics_url() << "\n";
  std::cout << std::flush;
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
  CheckFlagsFitMode(arguments);
  if (arguments.broker) return RunBroker(arguments);
  ServiceOptions& options = arguments.options;
  options.localizer.matcher = ParseMatcher(arguments.matcher);
  options.localizer.retrieval = ParseRetrievalMode(arguments.retrieval);
  options.curve_secret_key = ReadOptionalKey(arguments.curve_secret_key_file);
  options.curve_server_key = ReadOptionalKey(arguments.curve_server_key_file);
  options.curve_allowed_client_keys = ReadKeyList(arguments.curve_allowed_keys_file);
  options.curve_admin_keys = ReadKeyList(arguments.curve_admin_keys_file);
  // Queries run in parallel on the workers, each on one core (docs/decisions.md).
  SetComputeThreads(1);

  sigset_t signals = BlockSignals();

  LocalizationService service(arguments.map_dir, options);
  const std::string endpoint = service.Start();
  std::cout << fmt::format("listening on {}\nadmin on {}\n", endpoint, service.admin_endpoint());
  if (!service.metrics_url().empty()) std::cout << "metrics on " << service.metrics_url() << "\n";
  std::cout << std::flush;
  while (true) {
    int signal = 0;
    if (sigwait(&signals, &signal) != 0) continue;
    if (signal == SIGHUP) {
      // Not waited for here, so that a SIGTERM right after it waits for one reload at most.
      spdlog::info("SIGHUP: reloading {}", arguments.map_dir);
      service.RequestReload();
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
  command
      ->add_option("--admin-bind", options.admin_bind,
                   "Endpoint of this process's Reload and probes (Health); loopback or ipc:// "
                   "only, since whoever reaches it may reload ('': none)")
      ->capture_default_str();
  command
      ->add_option("--metrics-bind", options.metrics_bind,
                   "host:port of the Prometheus metrics (http://host:port/metrics; port 0: any "
                   "free port; '': none)")
      ->capture_default_str();
  command->add_flag("--broker", arguments->broker,
                    "Run as the broker: clients on --bind, workers on --backend");
  command->add_option("--backend", arguments->backend, "The broker's endpoint for workers")
      ->capture_default_str();
  command->add_option("--connect", options.connect,
                      "Work for the broker at this endpoint instead of binding; repeat the flag "
                      "for several brokers (each request is answered to the broker it came from)");
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
  command
      ->add_option("--max-keypoints", options.limits.max_keypoints,
                   "Keypoints per request; a request with more is refused")
      ->capture_default_str();
  command
      ->add_option("--max-matched-keypoints", options.localizer.max_matched_keypoints,
                   "Keypoints of a request matched at most, evenly spaced in its order; retrieval "
                   "pools them all (0: every keypoint)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  AddLastRoundOptions(*command, options.localizer);
  AddMatcherOption(*command, arguments->matcher);
  command->add_option("--top-k", options.localizer.top_k, "Retrieved images per query")
      ->capture_default_str();
  command
      ->add_option("--retrieval", arguments->retrieval,
                   "global (VLAD alone), global-then-votes (the network's point votes when VLAD's "
                   "candidates yield no pose) or votes")
      ->check(CLI::IsMember({"global", "global-then-votes", "votes"}))
      ->capture_default_str();
  command->add_option("--curve-secret-key", arguments->curve_secret_key_file,
                      "File with this process's CURVE secret key (hscloc keygen): a server's or "
                      "the broker front's key (encrypts and authenticates clients), or a "
                      "worker's own key (with --curve-server-key)");
  command->add_option("--curve-allowed-keys", arguments->curve_allowed_keys_file,
                      "File with the allowed clients' public keys, one per line");
  command->add_option("--curve-admin-keys", arguments->curve_admin_keys_file,
                      "File with the public keys that may also Reload on --bind, one per line");
  command->add_option("--curve-server-key", arguments->curve_server_key_file,
                      "A worker (--connect): file with the public key of the broker's backend");
  command->add_option("--backend-curve-secret-key", arguments->backend_curve_secret_key_file,
                      "The broker: file with its backend's CURVE secret key");
  command->add_option("--curve-allowed-worker-keys", arguments->curve_allowed_worker_keys_file,
                      "The broker: file with the workers' public keys, one per line (required "
                      "with --backend-curve-secret-key)");
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
