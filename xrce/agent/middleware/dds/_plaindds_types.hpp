// What the plain-DDS bridge (_plaindds.cpp) keeps: the byte-carrying type, its entities and
// a reader's listener. Included by _plaindds.cpp alone, after Python.h.

#ifndef XRCE_PLAINDDS_TYPES_HPP
#define XRCE_PLAINDDS_TYPES_HPP

#include <atomic>
#include <cstring>
#include <map>
#include <string>
#include <vector>

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/publisher/qos/DataWriterQos.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/DataReaderListener.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/subscriber/qos/DataReaderQos.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/dds/topic/TopicDataType.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>

// Fast DDS 3 (ROS 2 Kilted) moved what was eprosima::fastrtps into eprosima::fastdds, made
// ReturnCode_t a plain integer, DataWriter::write return one, and renamed TopicDataType's
// members; Fast DDS 2 (ROS 2 Jazzy) has its version in fastrtps/config.h, 3 in fastdds/config.hpp.
// The differences are all here and in BytesType: the rest of the bridge reads the same on both.
#if __has_include(<fastdds/config.hpp>)
#include <fastdds/config.hpp>
#else
#include <fastrtps/config.h>
#endif
#if defined(FASTDDS_VERSION_MAJOR) && FASTDDS_VERSION_MAJOR == 3
#define XRCE_FASTDDS_3 1
#elif !(defined(FASTRTPS_VERSION_MAJOR) && FASTRTPS_VERSION_MAJOR == 2)
#error "the plain DDS bridge knows Fast DDS 2 and 3 (build.py refuses others before compiling)"
#endif

namespace fdds = eprosima::fastdds::dds;
#ifdef XRCE_FASTDDS_3
namespace frtps = eprosima::fastdds::rtps;
using Duration = eprosima::fastdds::dds::Duration_t;
using RetCode = eprosima::fastdds::dds::ReturnCode_t;
constexpr RetCode RETCODE_OK = eprosima::fastdds::dds::RETCODE_OK;
#else
namespace frtps = eprosima::fastrtps::rtps;
using Duration = eprosima::fastrtps::Duration_t;
using RetCode = eprosima::fastrtps::types::ReturnCode_t;
const RetCode RETCODE_OK = RetCode::RETCODE_OK;
#endif
using frtps::InstanceHandle_t;
using frtps::SerializedPayload_t;

namespace {

constexpr uint32_t ENCAPSULATION = 4;
// The largest sample body either way. A board's sample is bounded by the agent's reassembly;
// one from a DDS peer would otherwise be bounded only by Fast DDS.
constexpr uint32_t MAX_SAMPLE = 64 * 1024;
// KEEP_ALL endpoints still hold at most this many samples.
constexpr int32_t KEEP_ALL_LIMIT = 1024;
const unsigned char ENCAPSULATION_LE[ENCAPSULATION] = {0x00, 0x01, 0x00, 0x00};

// What a writer hands Fast DDS: a board's body, borrowed from the Python bytes for the call.
struct Outgoing {
    const unsigned char* data;
    uint32_t size;
};

// What a reader takes: the whole payload, or nothing and ``oversize`` set.
struct Incoming {
    std::vector<unsigned char> payload;
    bool oversize = false;
};

// A board's body to and from the payload: the same work on both versions, under 2's and 3's
// names for it.
class BytesType : public fdds::TopicDataType {
public:
    explicit BytesType(const std::string& name)
    {
        // Only a payload pool's first size: the endpoints' memory policy grows it as needed.
#ifdef XRCE_FASTDDS_3
        set_name(name);
        max_serialized_type_size = 256 + ENCAPSULATION;
        is_compute_key_provided = false;
#else
        setName(name.c_str());
        m_typeSize = 256 + ENCAPSULATION;
        m_isGetKeyDefined = false;
#endif
    }

#ifdef XRCE_FASTDDS_3
    bool serialize(const void* const data, SerializedPayload_t& payload,
                   fdds::DataRepresentationId_t) override
    {
        return put(static_cast<const Outgoing*>(data), payload);
    }

    bool deserialize(SerializedPayload_t& payload, void* data) override
    {
        return take(payload, static_cast<Incoming*>(data));
    }

    uint32_t calculate_serialized_size(const void* const data, fdds::DataRepresentationId_t) override
    {
        return static_cast<const Outgoing*>(data)->size + ENCAPSULATION;
    }

    void* create_data() override { return new Incoming(); }

    void delete_data(void* data) override { delete static_cast<Incoming*>(data); }

    bool compute_key(SerializedPayload_t&, InstanceHandle_t&, bool) override { return false; }

    bool compute_key(const void* const, InstanceHandle_t&, bool) override { return false; }
#else
    bool serialize(void* data, SerializedPayload_t* payload) override
    {
        return put(static_cast<const Outgoing*>(data), *payload);
    }

    bool deserialize(SerializedPayload_t* payload, void* data) override
    {
        return take(*payload, static_cast<Incoming*>(data));
    }

    std::function<uint32_t()> getSerializedSizeProvider(void* data) override
    {
        uint32_t size = static_cast<const Outgoing*>(data)->size + ENCAPSULATION;
        return [size]() { return size; };
    }

    void* createData() override { return new Incoming(); }

    void deleteData(void* data) override { delete static_cast<Incoming*>(data); }

    bool getKey(void*, InstanceHandle_t*, bool) override { return false; }
#endif

private:
    static bool put(const Outgoing* sample, SerializedPayload_t& payload)
    {
        if (sample->size > MAX_SAMPLE || payload.max_size < sample->size + ENCAPSULATION) {
            return false;
        }
        std::memcpy(payload.data, ENCAPSULATION_LE, ENCAPSULATION);
        std::memcpy(payload.data + ENCAPSULATION, sample->data, sample->size);
        payload.length = sample->size + ENCAPSULATION;
        return true;
    }

    static bool take(const SerializedPayload_t& payload, Incoming* sample)
    {
        if (payload.length > MAX_SAMPLE + ENCAPSULATION || payload.length < ENCAPSULATION) {
            sample->payload.clear();
            sample->oversize = true;
            return true;  // taken and counted by the listener, not left in the history
        }
        sample->oversize = false;
        sample->payload.assign(payload.data, payload.data + payload.length);
        return true;
    }
};

// DataWriter::write answered a bool on Fast DDS 2 and a ReturnCode_t on 3.
inline bool write_sample(fdds::DataWriter* writer, Outgoing* sample)
{
#ifdef XRCE_FASTDDS_3
    return writer->write(sample) == RETCODE_OK;
#else
    return writer->write(sample);
#endif
}

struct ParticipantState;

struct TopicEntry {
    ParticipantState* owner;
    fdds::Topic* topic;
    std::string name;
    std::string type_name;
    int users;  // XRCE topics, writers and readers that hold it
};

struct ParticipantState {
    fdds::DomainParticipant* participant;
    fdds::Publisher* publisher = nullptr;
    fdds::Subscriber* subscriber = nullptr;
    int writers = 0;
    int readers = 0;
    std::map<std::string, TopicEntry*> topics;
};

struct Writer {
    TopicEntry* topic;
    fdds::DataWriter* writer;
    uint64_t oversize = 0;
};

class Reader : public fdds::DataReaderListener {
public:
    TopicEntry* topic = nullptr;
    fdds::DataReader* reader = nullptr;
    PyObject* callback = nullptr;  // owned; called with the GIL held
    std::atomic<bool> closed{false};
    std::atomic<uint64_t> taken{0};
    std::atomic<uint64_t> oversize{0};

    void on_data_available(fdds::DataReader* from) override
    {
        if (closed.load()) {
            return;
        }
        // Everything the history holds now, then the GIL once for the batch. The history is
        // bounded by the reader's QoS, and so is this.
        std::vector<std::vector<unsigned char>> batch;
        Incoming sample;
        fdds::SampleInfo info;
        while (from->take_next_sample(&sample, &info) == RETCODE_OK) {
            if (!info.valid_data) {
                continue;
            }
            if (sample.oversize) {
                oversize++;
                continue;
            }
            batch.emplace_back(std::move(sample.payload));
            sample.payload = std::vector<unsigned char>();
        }
        if (batch.empty() || closed.load()) {
            return;
        }
#if PY_VERSION_HEX >= 0x030D0000
        if (Py_IsFinalizing()) {
            return;
        }
#else
        if (_Py_IsFinalizing()) {
            return;
        }
#endif
        PyGILState_STATE gil = PyGILState_Ensure();
        for (auto& payload : batch) {
            if (closed.load()) {
                break;
            }
            PyObject* raw = PyBytes_FromStringAndSize(reinterpret_cast<const char*>(payload.data()),
                                                      static_cast<Py_ssize_t>(payload.size()));
            if (raw == nullptr) {
                PyErr_Clear();
                break;
            }
            taken++;
            PyObject* result = PyObject_CallOneArg(callback, raw);
            Py_DECREF(raw);
            if (result == nullptr) {
                PyErr_WriteUnraisable(callback);
            } else {
                Py_DECREF(result);
            }
        }
        PyGILState_Release(gil);
    }
};

}  // namespace

#endif
