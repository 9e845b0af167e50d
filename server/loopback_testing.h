// Test support for the service and the broker over real sockets: options bound to free loopback
// ports, clients that wait long and never retry, and a map whose loading the test holds.
#pragma once

#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <string>

#include "client/localization_client.h"
#include "server/broker.h"
#include "server/localization_service.h"

namespace hscloc::testing {

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
// `connect` set, a worker of that broker).
inline ServiceOptions LoopbackServiceOptions(const std::string& connect = "") {
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
  options.server = endpoint;
  options.timeout_ms = timeout_ms;
  options.retries = 0;
  return options;
}

// An ipc:// endpoint of this process; short, since a socket path holds at most 107 characters.
inline std::string IpcEndpoint(const std::string& name) {
  return "ipc:///tmp/hscloc-" + std::to_string(getpid()) + "-" + name;
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
