// The tev packet encoders against the worked bytes of tev-protocol.md, exactly,
// and against an independent decoder.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "client/tev_bridge.hpp"
#include "preview/tev_decoder.hpp"

namespace tally {
namespace {

std::string unhex(std::string_view hex) {
  std::string out;
  int hi = -1;
  for (char c : hex) {
    int v;
    if (c >= '0' && c <= '9') v = c - '0';
    else if (c >= 'a' && c <= 'f') v = c - 'a' + 10;
    else continue;  // spaces and newlines
    if (hi < 0) {
      hi = v;
    } else {
      out.push_back(static_cast<char>(hi * 16 + v));
      hi = -1;
    }
  }
  return out;
}

TEST(TevProtocol, CreateImageWorkedBytes) {
  const std::string expected = unhex("1f000000 04 01 6a6f622d343200 04000000 02000000 03000000 5200 4700 4200");
  ASSERT_EQ(expected.size(), 31u);
  EXPECT_EQ(tev::create_image("job-42", true, 4, 2, {"R", "G", "B"}), expected);
}

TEST(TevProtocol, UpdateImageV3WorkedBytes) {
  const std::string expected = unhex(R"(6f000000 06 00 6a6f622d343200 03000000 5200 4700 4200
    01000000 00000000 02000000 01000000
    0000000000000000 0100000000000000 0200000000000000
    0300000000000000 0300000000000000 0300000000000000
    0000803f 00000040 00004040 00008040 0000a040 0000c040)");
  ASSERT_EQ(expected.size(), 111u);
  const std::vector<float> data = {1, 2, 3, 4, 5, 6};
  EXPECT_EQ(tev::update_image_v3("job-42", false, {"R", "G", "B"}, 1, 0, 2, 1, {0, 1, 2}, {3, 3, 3}, data), expected);
}

TEST(TevProtocol, CloseImageWorkedBytes) {
  EXPECT_EQ(tev::close_image("img"), unhex("09000000 02 696d6700"));
}

TEST(TevProtocol, UpdateRejectsDataTooShortForItsRectangle) {
  const std::vector<float> data(5);
  EXPECT_THROW(tev::update_image_v3("x", false, {"R", "G", "B"}, 0, 0, 2, 1, {0, 1, 2}, {3, 3, 3}, data),
               std::invalid_argument);
  EXPECT_THROW(tev::update_image_v3("x", false, {"R"}, 0, 0, 1, 1, {0, 1}, {1}, data), std::invalid_argument);
}

TEST(TevProtocol, VectorGraphicsRoundTripsThroughTheDecoder) {
  const std::vector<tev::VgCommand> cmds = {
      {tev::kSave, {}, {}},
      {tev::kStrokeColor, {1, 0.5f, 0, 1}, {}},
      {tev::kBeginPath, {}, {}},
      {tev::kRect, {0.5f, 0.5f, 15, 15}, {}},
      {tev::kStroke, {}, {}},
      {tev::kText, {2, 10}, "64 spp"},
      {tev::kRestore, {}, {}},
  };
  const std::string bytes = tev::vector_graphics("img", false, false, cmds);
  const auto packets = test::decode_tev_stream(bytes);
  ASSERT_EQ(packets.size(), 1u);
  const auto& p = packets[0];
  EXPECT_EQ(p.type, 8);
  EXPECT_EQ(p.name, "img");
  EXPECT_FALSE(p.append);
  ASSERT_EQ(p.commands.size(), cmds.size());
  for (size_t i = 0; i < cmds.size(); ++i) {
    EXPECT_EQ(p.commands[i].type, cmds[i].type);
    EXPECT_EQ(p.commands[i].args, cmds[i].args);
    EXPECT_EQ(p.commands[i].text, cmds[i].text);
  }
  // A command with the wrong number of arguments is refused, not sent half-formed.
  EXPECT_THROW(tev::vector_graphics("img", false, false, {{tev::kRect, {1, 2, 3}, {}}}), std::invalid_argument);
  // An empty overlay (append = false, no commands) clears it.
  EXPECT_EQ(tev::vector_graphics("img", false, false, {}), unhex("0f000000 08 00 696d6700 00 00000000"));
}

TEST(TevProtocol, BridgeChannelsAreTheSpecifiedSeven) {
  EXPECT_EQ(tev::bridge_channels(),
            (std::vector<std::string>{"R", "G", "B", "StdErr.R", "StdErr.G", "StdErr.B", "SampleCount"}));
}

}  // namespace
}  // namespace tally
