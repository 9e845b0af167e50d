// Load on the localization service over loopback: throughput and latency percentiles at 1, 2, 4
// and 8 concurrent clients, beside the ideal throughput of the worker pool (workers / the mean
// latency of queries sent one at a time).
//   hscloc_server_load_benchmark CITY_DIR [REQUESTS_PER_CLIENT]
// CITY_DIR holds city/ and a trained map/ (tests/make_trained_city.sh makes one; the test suite's
// fixture is <build>/fixtures/small_city).
#include <fmt/format.h>

#include <algorithm>
#include <atomic>
#include <iostream>
#include <thread>

#include "client/localization_client.h"
#include "model/feature_io.h"
#include "model/query_io.h"
#include "server/localization_service.h"
#include "server/wire.h"
#include "util/logging.h"
#include "util/parallel.h"
#include "util/timer.h"

namespace hscloc {
namespace {

double Percentile(std::vector<double> values, double fraction) {
  std::sort(values.begin(), values.end());
  return values[std::min(values.size() - 1, static_cast<size_t>(fraction * values.size()))];
}

int Run(const std::filesystem::path& dir, int requests_per_client) {
  SetupLogging("warn");
  SetComputeThreads(1);
  std::vector<wire::LocalizeRequest> requests;
  const auto features = OpenH5Features(dir / "city" / "features.h5");
  for (const QueryWithIntrinsics& query :
       ReadQueryList(dir / "city" / "queries" / "day_time_queries_with_intrinsics.txt")) {
    ImageFeatures image = features->Read(query.name);
    requests.push_back(QueryToWire({query.name, query.camera, std::move(image.keypoints),
                                    std::move(image.descriptors), std::nullopt},
                                   true));
  }
  ServiceOptions options;
  options.bind = "tcp://127.0.0.1:0";
  options.workers = ResolveNumThreads(0);
  options.max_queue = 1024;
  LocalizationService service(dir / "map", options);
  const std::string endpoint = service.Start();
  ClientOptions client_options;
  client_options.server = endpoint;
  client_options.timeout_ms = 600000;

  std::cout << fmt::format(
      "{} workers on {} cores; {} requests per client, {} distinct day queries (mean {} "
      "keypoints)\n",
      options.workers, ResolveNumThreads(0), requests_per_client, requests.size(), [&] {
        size_t total = 0;
        for (const auto& request : requests) total += request.num_keypoints();
        return total / std::max<size_t>(1, requests.size());
      }());
  {
    // Warm-up: every distinct request once, so that first-touch costs stay out of the table.
    LocalizationClient client(client_options);
    for (const wire::LocalizeRequest& request : requests) client.Localize(request);
  }
  std::cout << "| clients | requests/s | p50 ms | p95 ms | p99 ms | of ideal |\n"
               "| --- | --- | --- | --- | --- | --- |\n";
  double single_throughput = 0;
  for (const int clients : {1, 2, 4, 8}) {
    std::vector<double> latencies;
    std::mutex mutex;
    Timer wall;
    std::vector<std::thread> threads;
    for (int c = 0; c < clients; ++c) {
      threads.emplace_back([&, c] {
        LocalizationClient client(client_options);
        for (int r = 0; r < requests_per_client; ++r) {
          const wire::LocalizeRequest& request = requests[(c * 7 + r) % requests.size()];
          Timer timer;
          const wire::LocalizeResponse response = client.Localize(request);
          const double ms = timer.ElapsedMilliseconds();
          if (response.status() != wire::OK && response.status() != wire::NOT_LOCALIZED) {
            std::cerr << "request failed: " << response.error_message() << '\n';
          }
          std::lock_guard<std::mutex> lock(mutex);
          latencies.push_back(ms);
        }
      });
    }
    for (std::thread& thread : threads) thread.join();
    const double throughput = latencies.size() / wall.ElapsedSeconds();
    // Ideal: every worker as busy as the single client kept one, i.e. workers / mean latency.
    if (clients == 1) single_throughput = throughput;
    const double ideal = options.workers * single_throughput;
    std::cout << fmt::format("| {} | {:.2f} | {:.1f} | {:.1f} | {:.1f} | {:.0f}% |\n", clients,
                             throughput, Percentile(latencies, 0.5), Percentile(latencies, 0.95),
                             Percentile(latencies, 0.99), 100 * throughput / ideal);
  }
  service.Stop();
  return 0;
}

}  // namespace
}  // namespace hscloc

int main(int argc, char** argv) {
  if (argc < 2) {
    std::cerr << "usage: hscloc_server_load_benchmark CITY_DIR [REQUESTS_PER_CLIENT]\n";
    return 2;
  }
  try {
    return hscloc::Run(argv[1], argc > 2 ? std::atoi(argv[2]) : 12);
  } catch (const std::exception& error) {
    std::cerr << "error: " << error.what() << '\n';
    return 1;
  }
}
