#include "client/localization_client.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cstring>
#include <thread>
#include <zmq.hpp>
#include <zmq_addon.hpp>

#include "util/half.h"
#include "util/random.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

TEST(ClientRequestTest, CameraTextParses) {
  const wire::Camera camera = ParseCamera("SIMPLE_RADIAL 1024 768 995 512 384 0.13");
  EXPECT_EQ(camera.model(), "SIMPLE_RADIAL");
  EXPECT_EQ(camera.width(), 1024u);
  EXPECT_EQ(camera.height(), 768u);
  ASSERT_EQ(camera.params_size(), 4);
  EXPECT_DOUBLE_EQ(camera.params(3), 0.13);
  EXPECT_THROW(ParseCamera("PINHOLE 640"), std::invalid_argument);
  EXPECT_THROW(ParseCamera("PINHOLE 640 480 500 5x0 320 240"), std::invalid_argument);
  EXPECT_THROW(ParseCamera("PINHOLE -640 480 1 1 1 1"), std::invalid_argument);
}

TEST(ClientRequestTest, PacksFloat32ExactlyAndFloat16ToNearest) {
  Random random(1);
  const uint32_t n = 37;
  const uint32_t d = 64;
  std::vector<float> keypoints(2 * n);
  std::vector<float> descriptors(n * d);
  for (float& value : keypoints) value = static_cast<float>(random.Uniform(0, 600));
  for (float& value : descriptors) value = static_cast<float>(random.Normal(0, 0.2));
  descriptors[0] = 70000.0f;  // beyond float16's range: infinity
  descriptors[1] = 1e-6f;     // a float16 subnormal
  const wire::Camera camera = ParseCamera("PINHOLE 640 480 500 500 320 240");
  const wire::LocalizeRequest exact =
      MakeLocalizeRequest("q.jpg", camera, keypoints, descriptors, d, false);
  EXPECT_EQ(exact.num_keypoints(), n);
  ASSERT_EQ(exact.keypoints().size(), keypoints.size() * 4);
  EXPECT_EQ(std::memcmp(exact.keypoints().data(), keypoints.data(), keypoints.size() * 4), 0);
  EXPECT_EQ(std::memcmp(exact.descriptors().data(), descriptors.data(), descriptors.size() * 4), 0);

  const wire::LocalizeRequest half =
      MakeLocalizeRequest("q.jpg", camera, keypoints, descriptors, d, true);
  EXPECT_EQ(half.descriptor_type(), wire::DESCRIPTOR_FLOAT16);
  ASSERT_EQ(half.descriptors().size(), descriptors.size() * 2);
  for (size_t i = 0; i < descriptors.size(); ++i) {
    uint16_t bits;
    std::memcpy(&bits, half.descriptors().data() + 2 * i, 2);
    // Bit-exact against the library's own conversion, which the server uses to decode.
    EXPECT_EQ(bits, FloatToHalfBits(descriptors[i])) << i << ": " << descriptors[i];
  }
  EXPECT_TRUE(std::isinf(HalfBitsToFloat(FloatToHalfBits(descriptors[0]))));
  EXPECT_THROW(MakeLocalizeRequest("q.jpg", camera, keypoints, {1.0f}, d, false),
               std::invalid_argument);
}

TEST(LocalizationClientTest, GivesUpWithinItsBoundWhenNoServerListens) {
  ClientOptions options;
  // Nothing listens on the discard ports: every connection is refused.
  options.servers = {"tcp://127.0.0.1:9", "tcp://127.0.0.1:19"};
  options.timeout_ms = 100;
  options.retries = 2;
  LocalizationClient client(options);
  const auto start = std::chrono::steady_clock::now();
  try {
    client.Health();
    FAIL() << "expected a ClientError";
  } catch (const ClientError& error) {
    EXPECT_THAT(error.what(), HasSubstr("no reply within 300 ms"));
    EXPECT_THAT(error.what(), HasSubstr("tcp://127.0.0.1:9 refused"));
    EXPECT_THAT(error.what(), HasSubstr("tcp://127.0.0.1:19 refused"));
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_GE(seconds, 0.25);  // the whole bound, (retries + 1) x 100 ms, tried round and round
  EXPECT_LT(seconds, 3.0);
}

TEST(LocalizationClientTest, AServerThatNeverAnswersTimesOutRetriesTimes) {
  zmq::context_t context(1);
  zmq::socket_t silent(context, zmq::socket_type::router);
  silent.bind("tcp://127.0.0.1:0");
  ClientOptions options;
  options.servers = {silent.get(zmq::sockopt::last_endpoint)};
  options.timeout_ms = 100;
  options.retries = 2;
  LocalizationClient client(options);
  try {
    client.Info();
    FAIL() << "expected a ClientError";
  } catch (const ClientError& error) {
    EXPECT_THAT(error.what(), HasSubstr("after 3 attempts"));
    EXPECT_THAT(error.what(), HasSubstr("timed out"));
  }
}

// Two stand-in servers on loopback, a client given both: the first one to die in the test.
struct TwoServers {
  TwoServers() {
    dying->bind("tcp://127.0.0.1:0");
    other.bind("tcp://127.0.0.1:0");
    options.servers = {dying->get(zmq::sockopt::last_endpoint),
                       other.get(zmq::sockopt::last_endpoint)};
  }
  // Waits for the first server's request and closes it unanswered: its connection drops.
  void TakeARequestAndDie() {
    std::vector<zmq::message_t> frames;
    ASSERT_TRUE(zmq::recv_multipart(*dying, std::back_inserter(frames)));
    dying.reset();
  }

  zmq::context_t context{1};
  std::unique_ptr<zmq::socket_t> dying =
      std::make_unique<zmq::socket_t>(context, zmq::socket_type::router);
  zmq::socket_t other{context, zmq::socket_type::router};
  ClientOptions options;
};

TEST(LocalizationClientTest, ARequestMovesToTheNextServerWhenItsServerDies) {
  TwoServers two;
  zmq::socket_t& healthy = two.other;
  const ClientOptions& options = two.options;
  two.options.timeout_ms = 20000;  // the failover must not wait for it
  LocalizationClient client(options);
  std::thread servers([&] {
    two.TakeARequestAndDie();
    std::vector<zmq::message_t> frames;
    ASSERT_TRUE(zmq::recv_multipart(healthy, std::back_inserter(frames)));
    ASSERT_EQ(frames.size(), 3u);
    wire::Response answer;
    answer.set_error_message("from the second server");
    healthy.send(frames[0], zmq::send_flags::sndmore);
    healthy.send(frames[1], zmq::send_flags::sndmore);
    healthy.send(zmq::buffer(answer.SerializeAsString()));
  });
  const auto start = std::chrono::steady_clock::now();
  wire::Request request;
  request.mutable_info();
  EXPECT_EQ(client.Call(request).error_message(), "from the second server");
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_LT(seconds, 5.0);
  EXPECT_EQ(client.failovers(), 1u);
  EXPECT_EQ(client.current_server(), options.servers[1]);
  servers.join();
}

TEST(LocalizationClientTest, AReloadIsNotResentToAnotherServer) {
  TwoServers two;
  LocalizationClient client(two.options);
  std::thread server([&] { two.TakeARequestAndDie(); });
  try {
    client.Reload();
    FAIL() << "expected a ClientError";
  } catch (const ClientError& error) {
    EXPECT_THAT(error.what(), HasSubstr("is not resent"));
  }
  server.join();
  zmq::pollitem_t item = {two.other.handle(), 0, ZMQ_POLLIN, 0};
  zmq::poll(&item, 1, std::chrono::milliseconds(300));
  EXPECT_FALSE(item.revents & ZMQ_POLLIN) << "the reload reached the other server";
}

// A server that ignores the first request and answers every later one, so the client must retry
// on a new socket; it also answers the ignored request late, which the client must discard.
TEST(LocalizationClientTest, RetriesOnANewSocketAndDropsLateReplies) {
  zmq::context_t context(1);
  zmq::socket_t router(context, zmq::socket_type::router);
  router.bind("tcp://127.0.0.1:0");
  const std::string endpoint = router.get(zmq::sockopt::last_endpoint);
  std::thread server([&] {
    std::vector<std::vector<zmq::message_t>> held;
    for (int received = 0; received < 2; ++received) {
      std::vector<zmq::message_t> frames;
      ASSERT_TRUE(zmq::recv_multipart(router, std::back_inserter(frames)));
      ASSERT_EQ(frames.size(), 3u);  // identity, call id, payload
      if (received == 0) {
        held.push_back(std::move(frames));
        continue;
      }
      wire::Response late;
      late.set_error_message("late");
      wire::Response answer;
      answer.set_error_message("answer");
      // The held request's reply goes to its old socket's identity, so a client that kept one
      // socket would see it first.
      router.send(held[0][0], zmq::send_flags::sndmore);
      router.send(held[0][1], zmq::send_flags::sndmore);
      router.send(zmq::buffer(late.SerializeAsString()));
      router.send(frames[0], zmq::send_flags::sndmore);
      router.send(frames[1], zmq::send_flags::sndmore);
      router.send(zmq::buffer(answer.SerializeAsString()));
    }
  });
  ClientOptions options;
  options.servers = {endpoint};
  options.timeout_ms = 300;
  options.retries = 1;
  LocalizationClient client(options);
  wire::Request request;
  request.mutable_health();
  const wire::Response response = client.Call(request);
  EXPECT_EQ(response.error_message(), "answer");
  server.join();
}

}  // namespace
}  // namespace hscloc
