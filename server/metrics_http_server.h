// The HTTP endpoint Prometheus scrapes: GET (or HEAD) /metrics answers the exposition text, any
// other path 404, any other method 405. One thread serves one connection at a time, each closed
// after its answer and given 2 s to send its request, so a stuck scraper delays the next scrape
// and nothing else.
//
// prometheus-cpp's own exposer runs civetweb, whose threads have a fixed 100 KiB stack; a process
// that links libtorch, OpenBLAS, glog and METIS needs about 130 KiB of static thread-local storage
// per thread, so glibc refuses to create them (EINVAL). This server's thread has the default stack.
#pragma once

#include <atomic>
#include <functional>
#include <string>
#include <thread>

namespace hscloc {

class MetricsHttpServer {
 public:
  // Listens on `bind` ("host:port", "[v6-host]:port"; port 0: a free one) and answers each scrape
  // with `exposition()`, called on the server's thread. Throws std::invalid_argument naming
  // `option` when the address is malformed or cannot be bound.
  MetricsHttpServer(const std::string& bind, const std::string& option,
                    std::function<std::string()> exposition);
  ~MetricsHttpServer();
  MetricsHttpServer(const MetricsHttpServer&) = delete;
  MetricsHttpServer& operator=(const MetricsHttpServer&) = delete;

  // "http://host:port/metrics", with the port as bound.
  const std::string& url() const { return url_; }

 private:
  void Loop();
  void Answer(int connection) const;

  std::function<std::string()> exposition_;
  int listener_ = -1;
  int stop_pipe_[2] = {-1, -1};
  std::string url_;
  std::thread thread_;
};

}  // namespace hscloc
