// Plain DDS topics of -m dds: DDS entities under exactly the names a client gave, carrying its CDR.
//
// Built at run time against the Fast DDS the ROS in use carries (xrce/agent/middleware/dds/build.py
// says why not by setup.py), loaded only after rmw_fastrtps_cpp has loaded that Fast DDS, so the
// library it links is the one already in the process. The entities live on the DomainParticipant
// rmw_fastrtps made for the domain's rclpy context: the same domain, profile and discovery as the
// ROS side, and no second participant to discover.
//
// The type carries bytes: serialize prepends the 4-byte XCDR1 little-endian encapsulation to a
// board's body, deserialize keeps the whole payload (the Python side strips those 4 bytes, as for
// ROS samples). No keys: every plain topic is NO_KEY. A sample larger than MAX_SAMPLE is dropped
// and counted, both ways: a DDS peer must not make the agent hold arbitrarily large samples.
//
// Threads: every call from Python holds the GIL, and releases it around each Fast DDS call that
// can wait for a Fast DDS thread (write, entity deletion): a reader's listener runs on such a
// thread and takes the GIL to hand its samples to Python.

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <dlfcn.h>
#include <link.h>

#include <cstring>
#include <map>
#include <string>

#include "_plaindds_types.hpp"

namespace {

// Every DomainParticipant the bridge has entities on, and what it keeps there (GIL held).
std::map<fdds::DomainParticipant*, ParticipantState*> participants;

// rmw_fastrtps_cpp::get_domain_participant and rcl_node_get_rmw_handle, looked up in the
// libraries rclpy loaded (neither is linked: a process whose RMW is another has neither).
using GetParticipant = fdds::DomainParticipant* (*)(void*);
using GetRmwNode = void* (*)(const void*);
GetParticipant get_participant = nullptr;
GetRmwNode get_rmw_node = nullptr;

// The path a library of that file name was loaded from: rcutils loads the RMW by its full
// path, which is the only name dlopen(RTLD_NOLOAD) then knows it by.
std::string loaded_path(const char* file_name)
{
    struct Search {
        const char* file_name;
        std::string found;
    } search{file_name, std::string()};
    dl_iterate_phdr(
        [](struct dl_phdr_info* info, size_t, void* data) -> int {
            Search* search = static_cast<Search*>(data);
            const char* path = info->dlpi_name;
            const char* slash = path ? std::strrchr(path, '/') : nullptr;
            if (slash != nullptr && std::strcmp(slash + 1, search->file_name) == 0) {
                search->found = path;
                return 1;
            }
            return 0;
        },
        &search);
    return search.found.empty() ? std::string(file_name) : search.found;
}

void* loaded_symbol(const char* library, const char* symbol)
{
    void* handle = dlopen(loaded_path(library).c_str(), RTLD_LAZY | RTLD_NOLOAD);
    if (handle == nullptr) {
        return nullptr;
    }
    void* found = dlsym(handle, symbol);
    dlclose(handle);
    return found;
}

PyObject* error(const std::string& text)
{
    PyErr_SetString(PyExc_RuntimeError, text.c_str());
    return nullptr;
}

template <typename T>
T* from_handle(PyObject* value)
{
    void* pointer = PyLong_AsVoidPtr(value);
    if (pointer == nullptr && !PyErr_Occurred()) {
        PyErr_SetString(PyExc_ValueError, "null handle");
    }
    return static_cast<T*>(pointer);
}

// -- participants and topics -------------------------------------------------------------------

PyObject* participant_of(PyObject*, PyObject* arg)
{
    void* node = PyLong_AsVoidPtr(arg);
    if (node == nullptr) {
        return PyErr_Occurred() ? nullptr : error("no rcl node");
    }
    if (get_rmw_node == nullptr) {
        get_rmw_node = reinterpret_cast<GetRmwNode>(loaded_symbol("librcl.so", "rcl_node_get_rmw_handle"));
    }
    if (get_participant == nullptr) {
        get_participant = reinterpret_cast<GetParticipant>(loaded_symbol(
            "librmw_fastrtps_cpp.so", "_ZN16rmw_fastrtps_cpp22get_domain_participantEP10rmw_node_s"));
    }
    if (get_rmw_node == nullptr || get_participant == nullptr) {
        return error("plain DDS topics need the rmw_fastrtps_cpp RMW loaded (it is not)");
    }
    void* rmw_node = get_rmw_node(node);
    fdds::DomainParticipant* participant = rmw_node ? get_participant(rmw_node) : nullptr;
    if (participant == nullptr) {
        return error("plain DDS topics need rmw_fastrtps_cpp: this node's RMW is another");
    }
    return PyLong_FromVoidPtr(participant);
}

void forget_participant_if_unused(ParticipantState* state)
{
    if (!state->topics.empty() || state->writers || state->readers) {
        return;
    }
    participants.erase(state->participant);
    delete state;
}

PyObject* topic_open(PyObject*, PyObject* args)
{
    PyObject* handle;
    const char* name;
    const char* type_name;
    if (!PyArg_ParseTuple(args, "Oss", &handle, &name, &type_name)) {
        return nullptr;
    }
    fdds::DomainParticipant* participant = from_handle<fdds::DomainParticipant>(handle);
    if (participant == nullptr) {
        return nullptr;
    }
    ParticipantState*& state = participants[participant];
    if (state == nullptr) {
        state = new ParticipantState();
        state->participant = participant;
    }
    auto known = state->topics.find(name);
    if (known != state->topics.end()) {
        if (known->second->type_name != type_name) {
            return error("topic '" + std::string(name) + "' is already of type '" +
                         known->second->type_name + "' in this domain");
        }
        known->second->users++;
        return PyLong_FromVoidPtr(known->second);
    }
    std::string other_type, refused;
    fdds::Topic* topic = nullptr;
    Py_BEGIN_ALLOW_THREADS
    fdds::TopicDescription* other = participant->lookup_topicdescription(name);
    if (other != nullptr) {
        other_type = other->get_type_name();
    } else {
        fdds::TypeSupport registered = participant->find_type(type_name);
        if (registered.empty()) {
            fdds::TypeSupport type(new BytesType(type_name));
            if (participant->register_type(type) != RETCODE_OK) {
                refused = "Fast DDS refused to register type '" + std::string(type_name) + "'";
            }
        } else if (dynamic_cast<BytesType*>(registered.get()) == nullptr) {
            refused = "type '" + std::string(type_name) + "' is one of the agent's ROS types";
        }
        if (refused.empty()) {
            topic = participant->create_topic(name, type_name, fdds::TOPIC_QOS_DEFAULT);
            if (topic == nullptr) {
                refused = "Fast DDS refused topic '" + std::string(name) + "'";
            }
        }
    }
    Py_END_ALLOW_THREADS
    if (!other_type.empty()) {
        return error("topic '" + std::string(name) + "' is already of type '" + other_type +
                     "' in this domain (a ROS topic of the agent)");
    }
    if (!refused.empty()) {
        forget_participant_if_unused(state);
        return error(refused);
    }
    TopicEntry* entry = new TopicEntry{state, topic, name, type_name, 1};
    state->topics[name] = entry;
    return PyLong_FromVoidPtr(entry);
}

void topic_release(TopicEntry* entry)
{
    if (--entry->users > 0) {
        return;
    }
    ParticipantState* state = entry->owner;
    fdds::DomainParticipant* participant = state->participant;
    state->topics.erase(entry->name);
    Py_BEGIN_ALLOW_THREADS
    participant->delete_topic(entry->topic);
    bool used = false;
    for (auto& other : state->topics) {
        used = used || other.second->type_name == entry->type_name;
    }
    if (!used) {
        participant->unregister_type(entry->type_name);
    }
    Py_END_ALLOW_THREADS
    delete entry;
    forget_participant_if_unused(state);
}

PyObject* topic_close(PyObject*, PyObject* arg)
{
    TopicEntry* entry = from_handle<TopicEntry>(arg);
    if (entry == nullptr) {
        return nullptr;
    }
    topic_release(entry);
    Py_RETURN_NONE;
}

// -- QoS ---------------------------------------------------------------------------------------

// (reliable, keep_last, depth, durability: 0 volatile, 1 transient local and beyond: Fast DDS has
// no persistence service here, so transient and persistent are transient local)
template <typename Qos>
void endpoint_qos(Qos& qos, int reliable, int keep_last, int depth, int durability)
{
    qos.reliability().kind = reliable ? fdds::RELIABLE_RELIABILITY_QOS : fdds::BEST_EFFORT_RELIABILITY_QOS;
    qos.durability().kind = durability ? fdds::TRANSIENT_LOCAL_DURABILITY_QOS : fdds::VOLATILE_DURABILITY_QOS;
    if (depth < 1) {
        depth = 1;
    }
    if (depth > KEEP_ALL_LIMIT) {
        depth = KEEP_ALL_LIMIT;
    }
    if (keep_last) {
        qos.history().kind = fdds::KEEP_LAST_HISTORY_QOS;
        qos.history().depth = depth;
        qos.resource_limits().max_samples = depth;
    } else {
        qos.history().kind = fdds::KEEP_ALL_HISTORY_QOS;
        qos.resource_limits().max_samples = KEEP_ALL_LIMIT;
    }
    qos.resource_limits().max_instances = 1;
    qos.resource_limits().max_samples_per_instance = qos.resource_limits().max_samples;
    qos.resource_limits().allocated_samples = depth < 16 ? depth : 16;
    qos.endpoint().history_memory_policy =
        frtps::PREALLOCATED_WITH_REALLOC_MEMORY_MODE;
}

// -- writers -----------------------------------------------------------------------------------

PyObject* writer_create(PyObject*, PyObject* args)
{
    PyObject* handle;
    int reliable, keep_last, depth, durability;
    if (!PyArg_ParseTuple(args, "Opppi", &handle, &reliable, &keep_last, &durability, &depth)) {
        return nullptr;
    }
    TopicEntry* topic = from_handle<TopicEntry>(handle);
    if (topic == nullptr) {
        return nullptr;
    }
    ParticipantState* state = topic->owner;
    fdds::Publisher* publisher = state->publisher;
    fdds::DataWriter* writer = nullptr;
    // Without the GIL: matching a reader of this participant takes that reader's lock, which its
    // listener may hold while it waits for the GIL.
    Py_BEGIN_ALLOW_THREADS
    if (publisher == nullptr) {
        publisher = state->participant->create_publisher(fdds::PUBLISHER_QOS_DEFAULT);
    }
    if (publisher != nullptr) {
        fdds::DataWriterQos qos = publisher->get_default_datawriter_qos();
        endpoint_qos(qos, reliable, keep_last, depth, durability);
        // A full KEEP_ALL history refuses the sample at once: the loop's thread never waits here.
        qos.reliability().max_blocking_time = Duration(0, 0);
        qos.publish_mode().kind = fdds::SYNCHRONOUS_PUBLISH_MODE;
        writer = publisher->create_datawriter(topic->topic, qos);
        if (writer == nullptr && state->writers == 0) {
            state->participant->delete_publisher(publisher);
            publisher = nullptr;
        }
    }
    Py_END_ALLOW_THREADS
    state->publisher = publisher;
    if (writer == nullptr) {
        return error("Fast DDS refused a datawriter on '" + topic->name + "'");
    }
    state->writers++;
    topic->users++;
    return PyLong_FromVoidPtr(new Writer{topic, writer});
}

PyObject* writer_write(PyObject*, PyObject* const* args, Py_ssize_t nargs)
{
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "write(writer, sample)");
        return nullptr;
    }
    Writer* writer = from_handle<Writer>(args[0]);
    if (writer == nullptr) {
        return nullptr;
    }
    Py_buffer view;
    if (PyObject_GetBuffer(args[1], &view, PyBUF_SIMPLE) != 0) {
        return nullptr;
    }
    if (view.len > MAX_SAMPLE) {
        PyBuffer_Release(&view);
        writer->oversize++;
        Py_RETURN_FALSE;
    }
    Outgoing sample{static_cast<const unsigned char*>(view.buf), static_cast<uint32_t>(view.len)};
    bool written;
    Py_BEGIN_ALLOW_THREADS
    written = write_sample(writer->writer, &sample);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&view);
    return PyBool_FromLong(written);
}

PyObject* writer_delete(PyObject*, PyObject* arg)
{
    Writer* writer = from_handle<Writer>(arg);
    if (writer == nullptr) {
        return nullptr;
    }
    ParticipantState* state = writer->topic->owner;
    fdds::Publisher* publisher = state->publisher;
    bool last = --state->writers == 0;
    Py_BEGIN_ALLOW_THREADS
    publisher->delete_datawriter(writer->writer);
    if (last) {
        state->participant->delete_publisher(publisher);
    }
    Py_END_ALLOW_THREADS
    if (last) {
        state->publisher = nullptr;
    }
    topic_release(writer->topic);
    delete writer;
    Py_RETURN_NONE;
}

PyObject* writer_matched(PyObject*, PyObject* arg)
{
    Writer* writer = from_handle<Writer>(arg);
    if (writer == nullptr) {
        return nullptr;
    }
    fdds::PublicationMatchedStatus status;
    Py_BEGIN_ALLOW_THREADS
    writer->writer->get_publication_matched_status(status);
    Py_END_ALLOW_THREADS
    return PyLong_FromLong(status.current_count);
}

// -- readers -----------------------------------------------------------------------------------

PyObject* reader_create(PyObject*, PyObject* args)
{
    PyObject* handle;
    PyObject* callback;
    int reliable, keep_last, depth, durability;
    if (!PyArg_ParseTuple(args, "OpppiO", &handle, &reliable, &keep_last, &durability, &depth,
                          &callback)) {
        return nullptr;
    }
    if (!PyCallable_Check(callback)) {
        PyErr_SetString(PyExc_TypeError, "callback is not callable");
        return nullptr;
    }
    TopicEntry* topic = from_handle<TopicEntry>(handle);
    if (topic == nullptr) {
        return nullptr;
    }
    ParticipantState* state = topic->owner;
    Reader* reader = new Reader();
    reader->topic = topic;
    Py_INCREF(callback);
    reader->callback = callback;
    fdds::Subscriber* subscriber = state->subscriber;
    fdds::DataReader* made = nullptr;
    // Without the GIL: the listener may run before create_datareader returns (a transient local
    // writer's history), and it takes the GIL.
    Py_BEGIN_ALLOW_THREADS
    if (subscriber == nullptr) {
        subscriber = state->participant->create_subscriber(fdds::SUBSCRIBER_QOS_DEFAULT);
    }
    if (subscriber != nullptr) {
        fdds::DataReaderQos qos = subscriber->get_default_datareader_qos();
        endpoint_qos(qos, reliable, keep_last, depth, durability);
        made = subscriber->create_datareader(topic->topic, qos, reader,
                                             fdds::StatusMask::data_available());
        if (made == nullptr && state->readers == 0) {
            state->participant->delete_subscriber(subscriber);
            subscriber = nullptr;
        }
    }
    Py_END_ALLOW_THREADS
    state->subscriber = subscriber;
    if (made == nullptr) {
        Py_DECREF(callback);
        delete reader;
        return error("Fast DDS refused a datareader on '" + topic->name + "'");
    }
    reader->reader = made;
    state->readers++;
    topic->users++;
    return PyLong_FromVoidPtr(reader);
}

PyObject* reader_delete(PyObject*, PyObject* arg)
{
    Reader* reader = from_handle<Reader>(arg);
    if (reader == nullptr) {
        return nullptr;
    }
    reader->closed.store(true);
    ParticipantState* state = reader->topic->owner;
    fdds::Subscriber* subscriber = state->subscriber;
    bool last = --state->readers == 0;
    // Without the GIL: deletion waits for a listener call in progress, which may wait for it.
    Py_BEGIN_ALLOW_THREADS
    subscriber->delete_datareader(reader->reader);
    if (last) {
        state->participant->delete_subscriber(subscriber);
    }
    Py_END_ALLOW_THREADS
    if (last) {
        state->subscriber = nullptr;
    }
    topic_release(reader->topic);
    Py_DECREF(reader->callback);
    delete reader;
    Py_RETURN_NONE;
}

PyObject* reader_counts(PyObject*, PyObject* arg)
{
    Reader* reader = from_handle<Reader>(arg);
    if (reader == nullptr) {
        return nullptr;
    }
    return Py_BuildValue("(KK)", static_cast<unsigned long long>(reader->taken.load()),
                         static_cast<unsigned long long>(reader->oversize.load()));
}

PyMethodDef methods[] = {
    {"participant_of", participant_of, METH_O,
     "participant_of(rcl_node_address) -> the DomainParticipant rmw_fastrtps made for its context"},
    {"topic_open", topic_open, METH_VARARGS,
     "topic_open(participant, topic_name, type_name) -> topic (one more user of it)"},
    {"topic_close", topic_close, METH_O, "topic_close(topic): one user fewer"},
    {"writer_create", writer_create, METH_VARARGS,
     "writer_create(topic, reliable, keep_last, durable, depth) -> writer"},
    {"writer_write", reinterpret_cast<PyCFunction>(reinterpret_cast<void (*)(void)>(writer_write)),
     METH_FASTCALL, "writer_write(writer, body) -> whether Fast DDS took it"},
    {"writer_delete", writer_delete, METH_O, "writer_delete(writer)"},
    {"writer_matched", writer_matched, METH_O, "writer_matched(writer) -> matched readers"},
    {"reader_create", reader_create, METH_VARARGS,
     "reader_create(topic, reliable, keep_last, durable, depth, on_sample) -> reader"},
    {"reader_delete", reader_delete, METH_O, "reader_delete(reader)"},
    {"reader_counts", reader_counts, METH_O,
     "reader_counts(reader) -> (samples handed on, samples dropped as too large)"},
    {nullptr, nullptr, 0, nullptr},
};

PyModuleDef module = {PyModuleDef_HEAD_INIT, "_plaindds", nullptr, -1, methods,
                      nullptr, nullptr, nullptr, nullptr};

}  // namespace

PyMODINIT_FUNC PyInit__plaindds(void)
{
    PyObject* made = PyModule_Create(&module);
    if (made == nullptr) {
        return nullptr;
    }
    if (PyModule_AddStringConstant(made, "SOURCE_CRC", XRCE_SOURCE_CRC) < 0 ||
        PyModule_AddIntConstant(made, "MAX_SAMPLE", MAX_SAMPLE) < 0) {
        Py_DECREF(made);
        return nullptr;
    }
    return made;
}
