# The control tree of the C++ example robot (learner.cpp), the same as `ktbt peer run`'s demo
# agent: deliver what it carries, use what it knows or has learned, walk at random otherwise.
# The robot runs control.xml, written by: ktbt convert examples/btcpp/control.sbt examples/btcpp/control.xml
<sl>
    <sq>
        <c>(Carrying)
        <a>(DeliverToZone)
    <e>
    <k>(prior)<e>
    <k>(new)<e>
    <a>(RandomWalk)
<e>
