#!/usr/bin/python3
"""PyTango's own Tango database server (tango.databaseds, Debian's python3-tango 9.3.6) with its
sqlite3 backend, for tests/tango/test_tango_db.py: enough of it repaired that a C++ device server
(libtango 9) starts against it and reads its device properties.

usage: pytango_database.py DIR [--port P] 2
(the database file: DIR/tango_database.db; the device sys/database/2 on port P: the schema
defines the database server's own devices for instance 2 only)

What 9.3.6's sqlite3 backend gets wrong, and what is replaced here (the rest is used as it is):
  * a new database file: SqlDatabase.create_db runs on the backend's one-thread executor and
    submits to it again (a deadlock), reading its .sql files from the current directory. The
    schema is created here with the backend's own statements.
  * DbGetDeviceProperty: NameError ('attribute'); DbGetClassProperty: NameError ('result');
    DbGetProperty: a count that is no string. Tango's C++ clients also expect one placeholder
    value after the count 0 of an empty property (as the C++ database server sends).
  * DbImportDevice, DbImportEvent: SQL with a stray '"' (and the reply's strings out of order).
  * DbPutDeviceProperty, DbPutDeviceAttributeProperty2, DbDeleteDeviceAttributeProperty: MySQL's
    INSERT ... SET, and a nested call on the one-thread executor (a deadlock that hangs the
    database for good). DbGetDevice/ClassAttributeProperty2: a property's last value count lost.
  * DbUnExportServer, DbUnExportDevice: MySQL's NOW().
  * exporting a device server notifies Starter devices (none here): off.
DbAddServer is not repaired ('/' for '//' under Python 3): add the devices one by one
(tango.Database.add_device). PyTango's own DbGetDataForServerCache answers nothing (left so: a
server then asks for each item on its own, as it does without a cache).
"""
import logging
import os
import sqlite3
import sys

from tango.databaseds import database
from tango.databaseds.db_access import sqlite3 as backend

DB_FILE = "tango_database.db"
use_cursor = backend.use_cursor


def create_schema(path):
    here = os.getcwd()
    os.chdir(os.path.dirname(database.__file__))  # the backend reads its .sql files from there
    try:
        statements = backend.get_create_db_statements()
    finally:
        os.chdir(here)
    conn = sqlite3.connect(path)
    for statement in statements:
        conn.execute(statement)
    conn.commit()
    conn.close()


def not_defined(what, origin):
    backend.th_exc(backend.DB_DeviceNotDefined, what + " not defined in the database !", origin)


@use_cursor
def import_device(self, dev_name):
    self.cursor.execute("SELECT exported, ior, version, pid, server, host, class FROM device "
                        "WHERE name = ? OR alias = ?", (dev_name, dev_name))
    row = self.cursor.fetchone()
    if row is None:
        not_defined("device " + dev_name, "DataBase::ImportDevice()")
    exported, ior, version, pid, server, host, klass = row
    return ([int(exported or 0), int(pid or 0)],
            [dev_name, ior or "", str(version or ""), server or "", host or "", klass or ""])


@use_cursor
def import_event(self, event_name):
    self.cursor.execute("SELECT exported, ior, version, pid, host FROM event WHERE name = ?",
                        (event_name,))
    row = self.cursor.fetchone()
    if row is None:
        not_defined("event " + event_name, "DataBase::ImportEvent()")
    exported, ior, version, pid, host = row
    return ([int(exported or 0), int(pid or 0)],
            [event_name, ior or "", str(version or ""), host or ""])


def read_properties(cursor, table, key, obj, names):
    result = [obj, str(len(names))]
    for name in names:
        cursor.execute("SELECT value FROM %s WHERE %s = ? AND name LIKE ? ORDER BY count"
                       % (table, key), (obj, backend.replace_wildcard(name)))
        values = [row[0] for row in cursor.fetchall()]
        result += [name, str(len(values))] + (values or [" "])
    return result


@use_cursor
def get_device_property(self, dev_name, properties):
    return read_properties(self.cursor, "property_device", "device", dev_name, properties)


@use_cursor
def get_class_property(self, class_name, properties):
    return read_properties(self.cursor, "property_class", "class", class_name, properties)


@use_cursor
def get_property(self, object_name, properties):
    return read_properties(self.cursor, "property", "object", object_name, properties)


@use_cursor
def put_device_property(self, device_name, nb_properties, values):
    domain, family, member = (device_name.split("/") + ["", "", ""])[:3]
    k = 0
    for _ in range(nb_properties):
        name, n = values[k], int(values[k + 1])
        self.cursor.execute("DELETE FROM property_device WHERE device = ? AND name = ?",
                            (device_name, name))
        for count, value in enumerate(values[k + 2:k + 2 + n], 1):
            self.cursor.execute(
                "INSERT INTO property_device (device, name, domain, family, member, count, value,"
                " updated, accessed) VALUES (?, ?, ?, ?, ?, ?, ?, datetime('now'),"
                " datetime('now'))", (device_name, name, domain, family, member, count, value))
        k += 2 + n


def read_attribute_properties(cursor, table, key, obj, attributes):
    result = [obj, str(len(attributes))]
    for attribute in attributes:
        cursor.execute("SELECT name, value FROM %s WHERE %s = ? AND attribute LIKE ? "
                       "ORDER BY name, count" % (table, key), (obj, attribute))
        props = {}
        for name, value in cursor.fetchall():
            props.setdefault(name, []).append(value)
        result += [attribute, str(len(props))]
        for name, values in props.items():
            result += [name, str(len(values))] + values
    return result


@use_cursor
def get_device_attribute_property2(self, dev_name, attributes):
    return read_attribute_properties(self.cursor, "property_attribute_device", "device",
                                     dev_name, attributes)


@use_cursor
def get_class_attribute_property2(self, class_name, attributes):
    return read_attribute_properties(self.cursor, "property_attribute_class", "class",
                                     class_name, attributes)


@use_cursor
def put_device_attribute_property2(self, device_name, nb_attributes, values):
    k = 0
    for _ in range(nb_attributes):
        attribute, nb_props = values[k], int(values[k + 1])
        k += 2
        for _ in range(nb_props):
            name, n = values[k], int(values[k + 1])
            self.cursor.execute("DELETE FROM property_attribute_device WHERE device = ? AND "
                                "attribute = ? AND name = ?", (device_name, attribute, name))
            for count, value in enumerate(values[k + 2:k + 2 + n], 1):
                self.cursor.execute(
                    "INSERT INTO property_attribute_device (device, attribute, name, count, "
                    "value, updated, accessed) VALUES (?, ?, ?, ?, ?, datetime('now'), "
                    "datetime('now'))", (device_name, attribute, name, count, value))
            k += 2 + n


@use_cursor
def delete_device_attribute_property(self, dev_name, attr_name, prop_name):
    self.cursor.execute("DELETE FROM property_attribute_device WHERE device = ? AND "
                        "attribute = ? AND name = ?", (dev_name, attr_name, prop_name))


@use_cursor
def unexport_server(self, server_name):
    self.cursor.execute("UPDATE device SET exported = 0, stopped = datetime('now') "
                        "WHERE server LIKE ?", (server_name,))


@use_cursor
def unexport_device(self, dev_name):
    self.cursor.execute("UPDATE device SET exported = 0, stopped = datetime('now') "
                        "WHERE name LIKE ?", (dev_name,))


def get_db(**keys):
    return backend.Executor.submit(backend.Sqlite3Database, fire_to_starter=False).result()


REPLACED = (import_device, import_event, get_device_property, get_class_property, get_property,
            put_device_property, get_device_attribute_property2, get_class_attribute_property2,
            put_device_attribute_property2, delete_device_attribute_property, unexport_server,
            unexport_device)


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    os.chdir(sys.argv[1])
    if not os.path.exists(DB_FILE):
        create_schema(DB_FILE)
    for f in REPLACED:
        setattr(backend.SqlDatabase, f.__name__, f)
    backend.get_db = get_db
    # Python's log on stderr: stdout carries only the ready line ("Ready to accept request").
    logging.basicConfig(stream=sys.stderr, level=logging.WARNING)
    database.main(sys.argv[2:])


if __name__ == "__main__":
    main()
