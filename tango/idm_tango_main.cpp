// idm-tango: the Tango device server of idmd's axes (README.md here).
//
//   idm-tango INSTANCE [-nodb -port P -dlist idm/axis/1,idm/axis/2] [Tango's other options]
//
// idmd's address comes from IDMD_SOCKET=path or IDMD_ADDRESS=host:port (default 127.0.0.1:5025),
// overridden by the device properties IdmdSocket / IdmdAddress when a Tango database is used.
#include <tango.h>

#include <cstring>
#include <iostream>
#include <string>
#include <vector>

#include "tango/idm_axis.h"

void Tango::DServer::class_factory() {
  add_class(idm::tango::IdmAxisClass::init("IdmAxis"));
}

int main(int argc, char** argv) {
  // `-port P` is the ORB's end point on every interface, as Tango's -ORBendPoint giop:tcp::P.
  std::vector<std::string> args;
  for (int i = 0; i < argc; ++i) {
    if (std::strcmp(argv[i], "-port") == 0 && i + 1 < argc) {
      args.push_back("-ORBendPoint");
      args.push_back(std::string("giop:tcp::") + argv[++i]);
    } else {
      args.push_back(argv[i]);
    }
  }
  std::vector<char*> targv;
  targv.reserve(args.size() + 1);
  for (std::string& a : args) targv.push_back(a.data());
  targv.push_back(nullptr);
  int targc = static_cast<int>(args.size());
  try {
    Tango::Util* tg = Tango::Util::init(targc, targv.data());
    tg->server_init(false);
    std::cout << "idm-tango: ready to accept requests" << std::endl;
    tg->server_run();
  } catch (const std::bad_alloc&) {
    std::cerr << "idm-tango: out of memory" << std::endl;
    return 1;
  } catch (const CORBA::Exception& e) {
    Tango::Except::print_exception(e);
    std::cerr << "idm-tango: exiting" << std::endl;
    return 1;
  }
  Tango::Util::instance()->server_cleanup();
  return 0;
}
