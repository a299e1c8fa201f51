// The files and directories a configuration names, checked before idmd touches a device (and by
// --check-config): what idmd reads must be what the lab put there, and what it writes must not be
// a path another user can redirect.
#pragma once

#include <string>
#include <vector>

#include "daemon/config.h"

namespace idm::daemon {

// The token of server.auth_token_file: the file's first line, without blanks around it. Refused
// (model::InputError naming the key, the file and why): not a regular file or a symbolic link,
// readable or writable by others than its owner and group, or a token shorter than 16 or longer
// than 256 characters, or holding characters other than letters, digits and -._~+/=.
std::string read_token_file(const std::string& path);

// "0640": a file mode's permission bits as chmod takes them.
std::string octal_mode(unsigned mode);

// What the files and directories of `config` say, for --check-config and the start (errors: idmd
// refuses to start, exit 2; warnings: it starts and logs them):
//  * the configuration file, recording.data_dir and the directories of every calibration_file and
//    reference_file: writable by every user (a directory without its sticky bit) is an error,
//    writable by a group or owned by another user (not root, not idmd's) a warning;
//  * the directory of a calibration_file or reference_file must exist and be writable by this
//    user (else the axis would lose what it learns); recording.data_dir not a directory, or not
//    writable (or, missing, not creatable) by this user is a warning (SWEEP would fail), missing
//    but creatable a note (idmd makes it at start). "This user" is the real user: idmd's own at
//    start; --check-config --user NAME takes NAME's permissions first (idmd_main.cpp);
//  * a calibration_file or reference_file that is there must be a regular file that reads as one
//    (idmd never overwrites a file it did not write: one that does not parse is an error naming
//    it, line and key).
struct FileFindings {
  std::vector<std::string> errors, warnings, notes;
};
FileFindings check_config_files(const DaemonConfig& config);

}  // namespace idm::daemon
