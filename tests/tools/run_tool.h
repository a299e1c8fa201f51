// Runs one of the project's tools from the build tree, as a user would, and keeps its exit status
// and its output (stdout and stderr together). Shared by the tools' end-to-end tests.
#pragma once

#include <sys/wait.h>

#include <cstdio>
#include <string>

namespace idm::test {

struct ToolResult {
  int status;       // exit status; -1 when the tool did not exit normally
  std::string out;  // stdout and stderr
};

// IDM_BUILD_DIR/tools/TOOL ARGS (ARGS as a shell would split them). With timeout_s > 0 the tool is
// killed after that long (status 124, or 137 after SIGKILL), so a tool that blocks cannot hang
// the suite.
inline ToolResult run_tool(const std::string& tool, const std::string& args, int timeout_s = 0) {
  const std::string prefix =
      timeout_s > 0 ? "timeout -k 5 " + std::to_string(timeout_s) + " " : std::string();
  const std::string cmd =
      prefix + std::string(IDM_BUILD_DIR) + "/tools/" + tool + " " + args + " 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  std::string out;
  char buf[4096];
  while (p && fgets(buf, sizeof buf, p)) out += buf;
  const int raw = p ? pclose(p) : -1;
  return {WIFEXITED(raw) ? WEXITSTATUS(raw) : -1, out};
}

}  // namespace idm::test
