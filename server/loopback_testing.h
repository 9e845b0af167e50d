// Test support for the service and the broker over real sockets: options bound to free loopback
// ports, clients that wait long and never retry, a map whose loading the test holds, and scrapes
// of the metrics endpoint.
#pragma once

#include <arpa/inet.h>
#include <fcntl.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <optional>
#include <sstream>
#include <string>

#include "client/localization_client.h"
#include "scene/feature_io.h"
#include "scene/query_io.h"
#include "server/broker.h"
#include "server/localization_service.h"
#include "server/wire.h"

namespace hscloc::testing {

// Localize requests for the first `limit` day queries of a synthetic city (its queries/ and
// features.h5), 3 retrieved images each to keep them short.
inline std::vector<wire::LocalizeRequest> DayQueryRequests(const std::filesystem::path& city,
                                                           size_t limit) {
  std::vector<wire::LocalizeRequest> requests;
  const auto features = OpenH5Features(city / "features.h5");
  for (const QueryWithIntrinsics& query :
       ReadQueryList(city / "queries" / "day_time_queries_with_intrinsics.txt")) {
    if (requests.size() == limit) break;
    ImageFeatures image = features->Read(query.name);
    requests.push_back(QueryToWire({query.name, query.camera, std::move(image.keypoints),
                                    std::move(image.descriptors), std::nullopt},
                                   true));
    requests.back().mutable_options()->set_top_k(3);
  }
  return requests;
}

// Every endpoint on a free loopback port, heartbeats every 100 ms.
inline BrokerOptions LoopbackBrokerOptions() {
  BrokerOptions options;
  options.front = "tcp://127.0.0.1:0";
  options.back = "tcp://127.0.0.1:0";
  options.admin_bind = "tcp://127.0.0.1:0";
  options.heartbeat_interval = std::chrono::milliseconds(100);
  return options;
}

// One worker thread, both endpoints on free loopback ports, heartbeats every 100 ms (with
// `connect` set, a worker of those brokers).
inline ServiceOptions LoopbackServiceOptions(const std::vector<std::string>& connect = {}) {
  ServiceOptions options;
  options.bind = "tcp://127.0.0.1:0";
  options.admin_bind = "tcp://127.0.0.1:0";
  options.connect = connect;
  options.workers = 1;
  options.heartbeat_interval = std::chrono::milliseconds(100);
  return options;
}

inline ClientOptions PatientClientOptions(const std::string& endpoint, int timeout_ms = 60000) {
  ClientOptions options;
  options.servers = {endpoint};
  options.timeout_ms = timeout_ms;
  options.retries = 0;
  return options;
}

// An ipc:// endpoint of this process; short, since a socket path holds at most 107 characters.
inline std::string IpcEndpoint(const std::string& name) {
  return "ipc:///tmp/hscloc-" + std::to_string(getpid()) + "-" + name;
}

// What the HTTP server at `url` ("http://host:port/path", an IPv4 host) answers `request`, sent as
// is; "{path}" in it stands for the URL's path. Fails the test (and returns "") when it cannot
// connect.
inline std::string HttpExchange(const std::string& url, const std::string& request) {
  const std::string scheme = "http://";
  const size_t host_end = url.find(':', scheme.size());
  const size_t port_end = url.find('/', scheme.size());
  if (url.rfind(scheme, 0) != 0 || host_end == std::string::npos || port_end == std::string::npos) {
    ADD_FAILURE() << "not an http://host:port/path URL: " << url;
    return "";
  }
  const std::string host = url.substr(scheme.size(), host_end - scheme.size());
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_port = htons(static_cast<uint16_t>(std::stoi(url.substr(host_end + 1))));
  if (inet_pton(AF_INET, host.c_str(), &address.sin_addr) != 1) {
    ADD_FAILURE() << "not an IPv4 address: " << host;
    return "";
  }
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  if (connect(fd, reinterpret_cast<const sockaddr*>(&address), sizeof(address)) != 0) {
    close(fd);
    ADD_FAILURE() << "cannot connect to " << url;
    return "";
  }
  std::string text = request;
  if (const size_t at = text.find("{path}"); at != std::string::npos) {
    text.replace(at, 6, url.substr(port_end));
  }
  EXPECT_EQ(write(fd, text.data(), text.size()), static_cast<ssize_t>(text.size()));
  std::string response;
  char buffer[4096];
  for (ssize_t n; (n = read(fd, buffer, sizeof(buffer))) > 0;) response.append(buffer, n);
  close(fd);
  return response;
}

// The body of an HTTP GET of `url`; fails the test (and returns "") on any error or a status
// other than 200.
inline std::string HttpGet(const std::string& url) {
  const std::string response = HttpExchange(url, "GET {path} HTTP/1.0\r\n\r\n");
  const size_t body = response.find("\r\n\r\n");
  if (response.rfind("HTTP/1.1 200", 0) != 0) {
    ADD_FAILURE() << "GET " << url << " answered: " << response.substr(0, body);
    return "";
  }
  return body == std::string::npos ? "" : response.substr(body + 4);
}

// The value of the sample `series` (a metric name with its labels in the exposition's order,
// e.g. hscloc_requests_total{kind="localize",status="OK"}) in a Prometheus text exposition, or
// nullopt when it is absent.
inline std::optional<double> MetricSample(const std::string& exposition,
                                          const std::string& series) {
  std::istringstream lines(exposition);
  for (std::string line; std::getline(lines, line);) {
    if (line.size() > series.size() && line.compare(0, series.size(), series) == 0 &&
        line[series.size()] == ' ') {
      return std::stod(line.substr(series.size() + 1));
    }
  }
  return std::nullopt;
}

// A copy of a map bundle whose manifest is a named pipe: loading it blocks in open() until
// Release writes the real manifest into the pipe, which holds the map in its LOADING state for
// as long as the test needs.
class HeldMap {
 public:
  HeldMap(const std::filesystem::path& from, const std::filesystem::path& to) : dir_(to) {
    std::filesystem::copy(from, to, std::filesystem::copy_options::recursive);
    std::ifstream file(to / "manifest.json", std::ios::binary);
    manifest_.assign(std::istreambuf_iterator<char>(file), std::istreambuf_iterator<char>());
    std::filesystem::remove(to / "manifest.json");
    EXPECT_EQ(mkfifo((to / "manifest.json").c_str(), 0600), 0);
  }
  // A load that never started (the test failed first) leaves no reader: the pipe is not waited on.
  ~HeldMap() {
    if (!released_) Write(O_WRONLY | O_NONBLOCK);
  }
  HeldMap(const HeldMap&) = delete;
  HeldMap& operator=(const HeldMap&) = delete;

  const std::filesystem::path& dir() const { return dir_; }
  // Lets the loading go on (once).
  void Release() {
    if (released_) return;
    released_ = true;
    EXPECT_TRUE(Write(O_WRONLY));
  }

 private:
  bool Write(int flags) {
    const int fd = open((dir_ / "manifest.json").c_str(), flags);
    if (fd < 0) return false;
    const bool written =
        write(fd, manifest_.data(), manifest_.size()) == static_cast<ssize_t>(manifest_.size());
    close(fd);
    return written;
  }

  std::filesystem::path dir_;
  std::string manifest_;
  bool released_ = false;
};

}  // namespace hscloc::testing
