// Replays fuzz inputs through a target's LLVMFuzzerTestOneInput without
// libFuzzer, so that the committed corpus runs in any sanitizer build (CI's
// ASan+UBSan lane, gcc) instead of needing a clang build of its own. Each
// argument is a file or a directory (read recursively, in sorted order);
// every input runs once. As libFuzzer's replay would, it fails on an input
// that takes longer than --timeout seconds or leaves the process's peak
// resident memory above --rss-limit-mb; sanitizer reports abort on their own.
//   replay_fuzzer [--timeout S] [--rss-limit-mb M] INPUT...
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <csignal>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

namespace {

const char* g_current = "";

void OnTimeout(int) {
  // Only async-signal-safe calls here.
  const char prefix[] = "replay: timeout on ";
  (void)!write(2, prefix, sizeof prefix - 1);
  (void)!write(2, g_current, std::char_traits<char>::length(g_current));
  (void)!write(2, "\n", 1);
  _exit(70);
}

std::vector<std::string> ExpandInputs(const std::vector<std::string>& args) {
  std::vector<std::string> files;
  for (const std::string& arg : args) {
    if (std::filesystem::is_directory(arg)) {
      for (const auto& entry : std::filesystem::recursive_directory_iterator(arg)) {
        if (entry.is_regular_file()) files.push_back(entry.path().string());
      }
    } else {
      files.push_back(arg);
    }
  }
  std::sort(files.begin(), files.end());
  return files;
}

long PeakRssMb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024;  // ru_maxrss is in KiB on Linux
}

}  // namespace

int main(int argc, char** argv) {
  unsigned timeout_seconds = 10;
  long rss_limit_mb = 2048;
  std::vector<std::string> args;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--timeout" && i + 1 < argc) {
      timeout_seconds = std::strtoul(argv[++i], nullptr, 10);
    } else if (arg == "--rss-limit-mb" && i + 1 < argc) {
      rss_limit_mb = std::strtol(argv[++i], nullptr, 10);
    } else {
      args.push_back(arg);
    }
  }
  const std::vector<std::string> files = ExpandInputs(args);
  if (files.empty()) {
    std::fprintf(stderr, "replay: no inputs (give files or directories)\n");
    return 2;
  }
  std::signal(SIGALRM, OnTimeout);
  for (const std::string& file : files) {
    std::ifstream in(file, std::ios::binary);
    if (!in) {
      std::fprintf(stderr, "replay: cannot read %s\n", file.c_str());
      return 2;
    }
    const std::vector<uint8_t> bytes{std::istreambuf_iterator<char>(in), {}};
    g_current = file.c_str();
    alarm(timeout_seconds);
    LLVMFuzzerTestOneInput(bytes.data(), bytes.size());
    alarm(0);
    if (PeakRssMb() > rss_limit_mb) {
      std::fprintf(stderr, "replay: %s took the peak resident memory to %ld MiB (limit %ld)\n",
                   file.c_str(), PeakRssMb(), rss_limit_mb);
      return 71;
    }
  }
  std::printf("replay: %zu inputs, peak resident memory %ld MiB\n", files.size(), PeakRssMb());
  return 0;
}
