// geodesicd serve's flags from the command line and from --config's
// `flags`: one parser, the command line winning, errors naming the line.
#include "server/app/serve_options.h"

#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace geodesic::server {
namespace {

using ::testing::HasSubstr;

class ServeOptionsTest : public ::testing::Test {
 protected:
  // A config file holding `text`, and its path.
  std::string Config(const std::string& text) {
    path_ = (std::filesystem::temp_directory_path() /
             ("serve_options_test_" + std::to_string(::getpid()) + ".yaml"))
                .string();
    std::ofstream(path_) << text;
    return path_;
  }
  void TearDown() override {
    if (!path_.empty()) std::filesystem::remove(path_);
  }

  // ParseServeOptions on `args` (after "geodesicd serve"), with what it
  // wrote to stderr.
  std::optional<int> Parse(std::vector<std::string> args, ServeOptions* out,
                           std::string* err = nullptr) {
    args.insert(args.begin(), {"geodesicd", "--no-sample"});
    std::vector<char*> argv;
    for (std::string& a : args) argv.push_back(a.data());
    ::testing::internal::CaptureStderr();
    std::optional<int> code = ParseServeOptions(static_cast<int>(argv.size()), argv.data(), out);
    const std::string written = ::testing::internal::GetCapturedStderr();
    if (err) *err = written;
    return code;
  }

  std::string path_;
};

TEST_F(ServeOptionsTest, FileFlagsAreParsedAsTheCommandLinesOwn) {
  ServeOptions o;
  const std::string config = Config(R"(
flags:
  max-pairs: 77
  memory-limit: 6G
  exact-fans: true
  idle-seconds: 5
)");
  ASSERT_EQ(Parse({"--config", config}, &o), std::nullopt);
  EXPECT_EQ(o.limits.max_pairs, 77);
  EXPECT_EQ(o.memory_limit, uint64_t{6} << 30);
  EXPECT_TRUE(o.limits.exact_fans);
  EXPECT_EQ(o.limits.idle_seconds, 5);
  // Flags the file does not name keep their defaults.
  EXPECT_EQ(o.limits.max_sources, ServiceLimits{}.max_sources);
}

TEST_F(ServeOptionsTest, TheCommandLineWins) {
  ServeOptions o;
  const std::string config = Config("flags:\n  max-pairs: 77\n  max-sources: 12\n");
  ASSERT_EQ(Parse({"--max-pairs", "9", "--config", config}, &o), std::nullopt);
  EXPECT_EQ(o.limits.max_pairs, 9);
  EXPECT_EQ(o.limits.max_sources, 12);
}

TEST_F(ServeOptionsTest, AnUnknownFlagIsRefusedNamingItsLine) {
  ServeOptions o;
  std::string err;
  const std::string config = Config("flags:\n  max-pairs: 7\n  max-pair: 7\n");
  EXPECT_EQ(Parse({"--config", config}, &o, &err), 2);
  EXPECT_THAT(err, HasSubstr(config + ":3:3: flags.max-pair"));
}

TEST_F(ServeOptionsTest, ABadValueIsRefusedNamingItsLine) {
  ServeOptions o;
  std::string err;
  const std::string config = Config("flags:\n  max-pairs: lots\n");
  EXPECT_EQ(Parse({"--config", config}, &o, &err), 2);
  EXPECT_THAT(err, HasSubstr(config + ":2:3: flags.max-pairs"));
  EXPECT_THAT(err, HasSubstr("lots"));

  const std::string range = Config("flags:\n  min-epsilon: 0.9\n");
  EXPECT_EQ(Parse({"--config", range}, &o, &err), 2);
  EXPECT_THAT(err, HasSubstr("flags.min-epsilon"));
}

TEST_F(ServeOptionsTest, AFileCannotNameAnotherOrSpellAFlagWithDashes) {
  ServeOptions o;
  std::string err;
  EXPECT_EQ(Parse({"--config", Config("flags:\n  config: other.yaml\n")}, &o, &err), 2);
  EXPECT_THAT(err, HasSubstr("cannot name another"));
  EXPECT_EQ(Parse({"--config", Config("flags:\n  --max-pairs: 3\n")}, &o, &err), 2);
  EXPECT_THAT(err, HasSubstr("without dashes"));
}

}  // namespace
}  // namespace geodesic::server
