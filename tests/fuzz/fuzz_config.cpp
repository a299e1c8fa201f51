// idmd's configuration loader: the fuzzer's bytes as the YAML file that load_daemon_config
// (daemon/config.h) reads at start and on SIGHUP, every section included (the stage, the
// interferometer, daq: with the sim, modbus and usb drivers' own sections, control, server,
// realtime, logging, recording, sim).
//
// The file is a memfd read through /proc/self/fd: the same path of the code as a file on disk.
//
// Invariants: a file is either accepted or refused with model::InputError, whose message starts
// with the file's name (every error names the file); nothing else is thrown; a control: section
// that the whole file's parse accepted is accepted by the SIGHUP reload (parse_control_config) too.
#include <sys/mman.h>
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>

#include "daemon/config.h"
#include "model/stage.h"
#include "model/yaml_util.h"

namespace {

[[noreturn]] void fail(const char* what, const std::string& detail) {
  std::fprintf(stderr, "fuzz_config: %s: %s\n", what, detail.c_str());
  std::abort();
}

// One memfd for the whole run, rewritten for every input.
const std::string& config_path() {
  static const std::string path = [] {
    const int fd = ::memfd_create("idmd.yaml", MFD_CLOEXEC);
    if (fd < 0) fail("memfd_create", "failed");
    return "/proc/self/fd/" + std::to_string(fd);
  }();
  return path;
}

void write_file(const std::uint8_t* data, std::size_t size) {
  const int fd = std::stoi(config_path().substr(config_path().rfind('/') + 1));
  if (::ftruncate(fd, 0) != 0) fail("ftruncate", config_path());
  std::size_t done = 0;
  while (done < size) {
    const ssize_t n = ::pwrite(fd, data + done, size - done, static_cast<off_t>(done));
    if (n <= 0) fail("pwrite", config_path());
    done += static_cast<std::size_t>(n);
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  write_file(data, size);
  const std::string& path = config_path();
  try {
    const idm::daemon::DaemonConfig config = idm::daemon::load_daemon_config(path);
    // What SIGHUP and *RST do with the same file.
    (void)idm::daemon::reload_control_configs(idm::model::load_yaml_file(path), path, config);
  } catch (const idm::model::InputError& e) {
    const std::string what = e.what();
    if (what.rfind(path, 0) != 0) fail("an error that does not name the file", what);
  } catch (const std::exception& e) {
    fail("an exception other than InputError", e.what());
  }
  return 0;
}
