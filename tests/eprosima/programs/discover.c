/* eProsima's client discovering agents: uxr_discovery_agents, unicast to argv's host and port
 * (IPv4, as the library discovers), one attempt a 1 s period each, three attempts. Prints
 * "AGENT <ipv4|ipv6> <address> <port>" per locator an agent answered with. */
#include "common.h"

#include <uxr/client/profile/discovery/discovery.h>

static bool on_agent(const TransportLocator *locator, void *args) {
    char ip[64];
    uint16_t port;
    uxrIpProtocol family;
    (void)args;
    if (uxr_locator_to_ip(locator, ip, sizeof ip, &port, &family))
        printf("AGENT %s %s %u\n", family == UXR_IPv6 ? "ipv6" : "ipv4", ip, port);
    else
        printf("AGENT unreadable\n");
    fflush(stdout);
    return false;  /* every locator of every answer */
}

int main(int argc, char **argv) {
    if (argc < 3) {
        fprintf(stderr, "usage: %s host port\n", argv[0]);
        return 2;
    }
    TransportLocator where;
    if (!uxr_ip_to_locator(argv[1], (uint16_t)atoi(argv[2]), UXR_IPv4, &where)) return 2;
    uxr_discovery_agents(2, 500, on_agent, NULL, &where, 1);
    return 0;
}
