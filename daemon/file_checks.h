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

}  // namespace idm::daemon
