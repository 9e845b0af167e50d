#include "server/reload_coalescer.h"

#include <gtest/gtest.h>

#include <atomic>
#include <future>
#include <thread>

namespace hscloc {
namespace {

// A reload that blocks until the test opens its gate, so that requests can be made while it runs.
struct GatedReload {
  std::promise<void> started;
  std::shared_future<void> gate;
  std::atomic<int> runs{0};

  ReloadOutcome operator()() {
    if (runs++ == 0) started.set_value();
    gate.wait();
    ReloadOutcome outcome;
    outcome.success = true;
    outcome.map_id = "map" + std::to_string(runs.load());
    return outcome;
  }
};

TEST(ReloadCoalescerTest, RequestsDuringAReloadShareTheOneAfterIt) {
  std::promise<void> open;
  GatedReload gated;
  gated.gate = open.get_future().share();
  ReloadCoalescer coalescer([&] { return gated(); });
  std::atomic<int> first_outcomes{0};
  std::atomic<int> later_outcomes{0};
  ASSERT_TRUE(coalescer.Request([&](const ReloadOutcome& outcome) {
    EXPECT_EQ(outcome.map_id, "map1");
    ++first_outcomes;
  }));
  gated.started.get_future().wait();
  std::promise<void> all_done;
  constexpr int kLater = 500;
  for (int i = 0; i < kLater; ++i) {
    ASSERT_TRUE(coalescer.Request([&](const ReloadOutcome& outcome) {
      EXPECT_TRUE(outcome.success);
      EXPECT_EQ(outcome.map_id, "map2");  // a reload that started after the request
      if (++later_outcomes == kLater) all_done.set_value();
    }));
  }
  open.set_value();
  all_done.get_future().wait();
  EXPECT_EQ(first_outcomes.load(), 1);
  EXPECT_EQ(coalescer.reloads_executed(), 2u);
  EXPECT_EQ(gated.runs.load(), 2);
}

TEST(ReloadCoalescerTest, StopWaitsForTheRunningReloadAndCancelsTheWaitingOnes) {
  std::promise<void> open;
  GatedReload gated;
  gated.gate = open.get_future().share();
  ReloadCoalescer coalescer([&] { return gated(); });
  std::atomic<int> succeeded{0};
  std::atomic<int> cancelled{0};
  const auto count = [&](const ReloadOutcome& outcome) {
    outcome.cancelled ? ++cancelled : outcome.success ? ++succeeded : 0;
  };
  ASSERT_TRUE(coalescer.Request(count));
  gated.started.get_future().wait();
  for (int i = 0; i < 10; ++i) ASSERT_TRUE(coalescer.Request(count));
  std::thread stopper([&] { coalescer.Stop(); });
  // The gate opens only once Stop has begun (requests are refused), so the running reload cannot
  // finish first and start another for the waiting ones. Probes accepted before that are
  // cancelled with them, apart from the count.
  while (coalescer.Request([](const ReloadOutcome&) {})) std::this_thread::yield();
  open.set_value();
  stopper.join();
  EXPECT_EQ(succeeded.load(), 1);
  EXPECT_EQ(cancelled.load(), 10);
  EXPECT_EQ(gated.runs.load(), 1);
  EXPECT_TRUE(coalescer.stopped());
  EXPECT_FALSE(coalescer.Request(count));
  EXPECT_TRUE(coalescer.RequestAndWait().cancelled);
}

TEST(ReloadCoalescerTest, RequestAndWaitReturnsTheOutcome) {
  ReloadCoalescer coalescer([] {
    ReloadOutcome outcome;
    outcome.error_message = "label_tree.bin is corrupt";
    return outcome;
  });
  const ReloadOutcome outcome = coalescer.RequestAndWait();
  EXPECT_FALSE(outcome.success);
  EXPECT_FALSE(outcome.cancelled);
  EXPECT_EQ(outcome.error_message, "label_tree.bin is corrupt");
}

}  // namespace
}  // namespace hscloc
