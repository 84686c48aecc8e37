// What an error message repeats of a client's input (server/base/echo.h).
#include "server/base/echo.h"

#include <string>

#include "gtest/gtest.h"

namespace geodesic::server {
namespace {

TEST(CutTest, ShortTextIsKeptAsIs) {
  EXPECT_EQ(Cut("mesh-7"), "mesh-7");
  EXPECT_EQ(Cut(std::string(kMaxEcho, 'a')), std::string(kMaxEcho, 'a'));
}

TEST(CutTest, LongTextIsCutAndItsLengthNamed) {
  const std::string cut = Cut(std::string(1000, 'a'));
  EXPECT_EQ(cut, std::string(kMaxEcho, 'a') + "... (1000 bytes)");
}

TEST(CutTest, NeverSplitsAUtf8Character) {
  // 79 ASCII bytes, then a two-byte character straddling the cut.
  const std::string text = std::string(kMaxEcho - 1, 'a') + "\xC3\xA9" + std::string(50, 'b');
  const std::string cut = Cut(text);
  EXPECT_EQ(cut, std::string(kMaxEcho - 1, 'a') + "... (131 bytes)");
}

TEST(EchoTest, EscapesControlAndNonAsciiBytes) { EXPECT_EQ(Echo("a\nb\xff"), "a\\nb\\xff"); }

TEST(EchoTest, LongInputIsCutAfterEscaping) {
  const std::string echo = Echo(std::string(500, '\x01'));
  EXPECT_TRUE(echo.ends_with("... (500 bytes)")) << echo;
  EXPECT_LT(echo.size(), 4 * kMaxEcho + 20);
}

}  // namespace
}  // namespace geodesic::server
