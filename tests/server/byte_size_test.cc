// Sizes as operators write them.
#include "server/base/byte_size.h"

#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace geodesic::server {
namespace {

TEST(ByteSizeTest, NumbersAndBinarySuffixes) {
  const std::pair<const char*, uint64_t> cases[] = {
      {"0", 0},
      {"123", 123},
      {"64K", 64 << 10},
      {"64kb", 64 << 10},
      {"512M", uint64_t{512} << 20},
      {"6G", uint64_t{6} << 30},
      {"6GiB", uint64_t{6} << 30},
      {" 1.5g ", uint64_t{3} << 29},
      {"2T", uint64_t{2} << 40},
      {"100B", 100},
  };
  for (const auto& [text, bytes] : cases) {
    auto parsed = ParseByteSize(text, "--memory-limit");
    ASSERT_TRUE(parsed.ok()) << text << ": " << parsed.status();
    EXPECT_EQ(*parsed, bytes) << text;
  }
}

TEST(ByteSizeTest, AnythingElseIsRefusedNamingFlagAndText) {
  for (const char* text : {"", "G", "6X", "six", "-1", "1.2.3G", "6 G B", "1e3", "99999999999T"}) {
    auto parsed = ParseByteSize(text, "--disk-limit");
    ASSERT_FALSE(parsed.ok()) << text;
    EXPECT_EQ(parsed.status().code(), absl::StatusCode::kInvalidArgument);
    EXPECT_THAT(std::string(parsed.status().message()), ::testing::HasSubstr("--disk-limit"));
  }
}

}  // namespace
}  // namespace geodesic::server
