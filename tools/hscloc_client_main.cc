// hscloc-client: sends queries to an hscloc server. Links the client library, protobuf, ZeroMQ,
// OpenCV and the feature readers, never libtorch, FAISS or Ceres (a test checks its libraries).
#include <fmt/format.h>
#include <fmt/ranges.h>

#include <CLI/CLI.hpp>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <map>

#include "client/batch_runner.h"
#include "client/localization_client.h"
#include "features/feature_extractor.h"
#include "scene/feature_io.h"
#include "scene/query_io.h"
#include "util/timer.h"

namespace hscloc {
namespace {

void PrintResponse(const wire::LocalizeResponse& response) {
  std::cout << fmt::format(
      "{}: {}{}\n", response.request_id(), wire::Status_Name(response.status()),
      response.error_message().empty() ? "" : " (" + response.error_message() + ")");
  if (response.status() == wire::OK || response.status() == wire::NOT_LOCALIZED) {
    const wire::Pose& pose = response.cam_from_world();
    std::cout << fmt::format(
        "  cam_from_world  q {:.6f} {:.6f} {:.6f} {:.6f}  t {:.4f} {:.4f} {:.4f}\n"
        "  inliers {}  retrieved image {} ({})\n",
        pose.qw(), pose.qx(), pose.qy(), pose.qz(), pose.tx(), pose.ty(), pose.tz(),
        response.num_inliers(), response.retrieved_image_name(), response.retrieved_image_id());
    const wire::StageTimings& t = response.timings();
    std::cout << fmt::format(
        "  ms: retrieval {:.1f}, match {:.1f}, visibility {:.1f}, pose {:.1f}, localizer "
        "{:.1f}, "
        "server {:.1f}\n",
        t.retrieval_ms(), t.match_ms(), t.visibility_ms(), t.pose_ms(), t.total_ms(),
        t.server_ms());
  }
}

struct CommonArguments {
  ClientOptions client;
  std::string curve_server_key_file;
  std::string curve_secret_key_file;
  bool float16 = true;
};

// The first 40 characters of a key file's first line; empty for no file.
std::string ReadKeyFile(const std::string& path) {
  if (path.empty()) return "";
  std::ifstream file(path);
  std::string key;
  if (!file || !std::getline(file, key) || key.size() < 40) {
    throw std::invalid_argument("cannot read a Z85 key from " + path);
  }
  return key.substr(0, 40);
}

void ResolveKeys(CommonArguments& common) {
  common.client.curve_server_key = ReadKeyFile(common.curve_server_key_file);
  common.client.curve_secret_key = ReadKeyFile(common.curve_secret_key_file);
}

int RunBatchCommand(CommonArguments& common, const std::vector<std::string>& lists,
                    const std::string& features_path, const std::string& out, int inflight) {
  ResolveKeys(common);
  std::vector<QueryWithIntrinsics> queries;
  for (const std::string& list : lists) {
    for (QueryWithIntrinsics& query : ReadQueryList(list)) queries.push_back(std::move(query));
  }
  BatchOptions options;
  options.client = common.client;
  options.out = out;
  options.inflight = inflight;
  options.float16 = common.float16;
  const BatchSummary summary = RunBatch(queries, *OpenFeatureReader(features_path), options);
  std::cout << fmt::format("localized {} of {} queries ({} failed) in {} with {} in flight\n",
                           summary.num_localized, summary.num_queries, summary.num_failed,
                           FormatDuration(summary.seconds), inflight);
  return summary.num_failed == summary.num_queries && summary.num_queries > 0 ? 1 : 0;
}

using CommandRunner = std::function<int()>;

// A broker's workers and the maps they serve: ", 2 workers (1 on city@ab12..., 1 on ...)".
std::string WorkersText(const wire::HealthResponse& health) {
  if (health.workers() == 0) return "";
  std::map<std::string, int> by_map;
  for (const wire::WorkerStatus& worker : health.worker_status()) ++by_map[worker.map_id()];
  std::vector<std::string> maps;
  for (const auto& [map_id, count] : by_map) maps.push_back(fmt::format("{} on {}", count, map_id));
  return fmt::format(", {} workers ({})", health.workers(), fmt::join(maps, ", "));
}

// The options every subcommand shares: the server, its timeouts and retries, CURVE keys and the
// descriptors' precision.
void AddCommonOptions(CLI::App& app, CommonArguments& common) {
  app.add_option("--server", common.client.servers,
                 "Server endpoint; repeat for several equivalent servers (brokers): a request "
                 "moves to the next when its server dies, refuses or times out")
      ->allow_extra_args(false)
      ->capture_default_str();
  app.add_option("--timeout-ms", common.client.timeout_ms, "Reply timeout per attempt")
      ->capture_default_str();
  app.add_option("--retries", common.client.retries,
                 "Attempts after the first that may time out, each on the next server")
      ->capture_default_str();
  app.add_option("--curve-server-key", common.curve_server_key_file,
                 "File with the server's CURVE public key (encrypted connection)");
  app.add_option("--curve-secret-key", common.curve_secret_key_file,
                 "File with this client's CURVE secret key, for servers that allow listed keys "
                 "only (default: a fresh key pair)");
  auto float32 = std::make_shared<bool>(false);
  app.add_flag("--float32", *float32,
               "Send descriptors as float32 (default float16: half the bytes, results may differ "
               "in the last bits)");
  app.parse_complete_callback([&common, float32] { common.float16 = !*float32; });
}

void AddQueryCommand(CLI::App& app, CommonArguments& common, CommandRunner& run) {
  CLI::App* query = app.add_subcommand("query", "Localize one photo or one image's features");
  auto image = std::make_shared<std::string>();
  auto features = std::make_shared<std::string>();
  auto name = std::make_shared<std::string>();
  auto camera = std::make_shared<std::string>();
  query->add_option("--image", *image, "Photo: its features are extracted here (--feature)")
      ->check(CLI::ExistingFile);
  auto feature = std::make_shared<std::string>("sift");
  auto extractor_options = std::make_shared<FeatureExtractorOptions>();
  query->add_option("--feature", *feature, "Features of --image: sift or xfeat (as the map's)")
      ->check(CLI::IsMember({"sift", "xfeat"}))
      ->capture_default_str();
  query->add_option("--xfeat-model", extractor_options->xfeat.model_path, "XFeat ONNX model")
      ->capture_default_str();
  query
      ->add_option("--xfeat-max-side", extractor_options->xfeat.max_side_px,
                   "Longer side of the photo as XFeat sees it (as the map's features)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  query->add_option("--features", *features, "Features file (.h5 or database.db)")
      ->check(CLI::ExistingFile);
  query->add_option("--name", *name, "Image name in --features (default: the photo's name)");
  query->add_option("--camera", *camera, "\"MODEL WIDTH HEIGHT PARAMS...\"")->required();
  query->callback([&, image, features, name, camera, feature, extractor_options] {
    run = [&, image, features, name, camera, feature, extractor_options] {
      ResolveKeys(common);
      const wire::Camera wire_camera = ParseCamera(*camera);
      wire::LocalizeRequest request;
      if (!image->empty()) {
        extractor_options->type = ParseFeatureType(*feature);
        const ExtractedFeatures extracted =
            CreateFeatureExtractor(*extractor_options)->Extract(*image);
        request = RequestFromFeatures(name->empty() ? *image : *name, wire_camera,
                                      extracted.features, common.float16);
      } else if (!features->empty() && !name->empty()) {
        request = RequestFromFeatures(*name, wire_camera, OpenFeatureReader(*features)->Read(*name),
                                      common.float16);
      } else {
        throw std::invalid_argument("query: give --image, or --features with --name");
      }
      LocalizationClient client(common.client);
      const wire::LocalizeResponse response = client.Localize(request);
      PrintResponse(response);
      return response.status() == wire::OK ? 0 : 1;
    };
  });
}

void AddBatchCommand(CLI::App& app, CommonArguments& common, CommandRunner& run) {
  CLI::App* batch = app.add_subcommand("batch", "Localize a query list; write a submission file");
  auto lists = std::make_shared<std::vector<std::string>>();
  auto features = std::make_shared<std::string>();
  auto out = std::make_shared<std::string>();
  auto inflight = std::make_shared<int>(16);
  batch->add_option("--queries", *lists, "Query list(s): NAME MODEL WIDTH HEIGHT PARAMS...")
      ->required()
      ->check(CLI::ExistingFile);
  batch->add_option("--features", *features, "Features file (.h5 or database.db)")
      ->required()
      ->check(CLI::ExistingFile);
  batch->add_option("--out", *out, "Submission file")->required();
  batch->add_option("--inflight", *inflight, "Requests in flight")->capture_default_str();
  batch->callback([&, lists, features, out, inflight] {
    run = [&, lists, features, out, inflight] {
      return RunBatchCommand(common, *lists, *features, *out, *inflight);
    };
  });
}

void AddHealthCommand(CLI::App& app, CommonArguments& common, CommandRunner& run) {
  CLI::App* health = app.add_subcommand(
      "health",
      "Ask a process whether it is ready (exit 0) or not (1); on its admin endpoint, "
      "the probe of that process alone");
  auto live = std::make_shared<bool>(false);
  health->add_flag("--live", *live,
                   "Liveness: exit 0 on any reply, ready or not (e.g. still loading its map)");
  health->callback([&, live] {
    run = [&, live] {
      ResolveKeys(common);
      LocalizationClient client(common.client);
      const wire::HealthResponse response = client.Health();
      std::cout << fmt::format(
          "{} map {} up {:.0f} s, {} queued{}{}\n", wire::Status_Name(response.status()),
          response.map_id(), response.uptime_s(), response.queued_requests(), WorkersText(response),
          response.reason().empty() ? "" : ": " + response.reason());
      return *live || response.status() == wire::OK ? 0 : 1;
    };
  });
}

void AddReloadCommand(CLI::App& app, CommonArguments& common, CommandRunner& run) {
  CLI::App* reload = app.add_subcommand(
      "reload", "Reload the server's map (its admin endpoint, or with an admin CURVE key)");
  reload->callback([&] {
    run = [&] {
      ResolveKeys(common);
      LocalizationClient client(common.client);
      const wire::ReloadResponse response = client.Reload();
      std::cout << fmt::format(
          "{} map {}{}\n", wire::Status_Name(response.status()), response.map_id(),
          response.error_message().empty() ? "" : ": " + response.error_message());
      return response.status() == wire::OK ? 0 : 1;
    };
  });
}

void AddInfoCommand(CLI::App& app, CommonArguments& common, CommandRunner& run) {
  CLI::App* info = app.add_subcommand("info", "Show the served map's description");
  info->callback([&] {
    run = [&] {
      ResolveKeys(common);
      LocalizationClient client(common.client);
      std::cout << client.Info().DebugString();
      return 0;
    };
  });
}

}  // namespace
}  // namespace hscloc

int main(int argc, char** argv) {
  using namespace hscloc;
  CLI::App app{"hscloc-client: localize photos or features against an hscloc server"};
  app.require_subcommand(1);
  // The global options work on either side of the subcommand (`batch --server X`): what a
  // subcommand does not know falls through to them. Subcommands inherit this when added.
  app.fallthrough();
  app.set_version_flag("--version", "hscloc-client 0.1.0");
  CommonArguments common;
  AddCommonOptions(app, common);
  std::function<int()> run;

  AddQueryCommand(app, common, run);
  AddBatchCommand(app, common, run);
  AddHealthCommand(app, common, run);
  AddReloadCommand(app, common, run);
  AddInfoCommand(app, common, run);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& error) {
    return app.exit(error);
  }
  try {
    return run();
  } catch (const std::invalid_argument& error) {
    std::fprintf(stderr, "error: %s\n", error.what());
    return 2;
  } catch (const std::exception& error) {
    std::fprintf(stderr, "failed: %s\n", error.what());
    return 1;
  }
}
