<?xml version="1.0" encoding="UTF-8"?>
<tileset version="1.10" tiledversion="1.10.2" name="ledges" tilewidth="16" tileheight="16" tilecount="3" columns="3">
 <image source="ledges.png" width="48" height="16"/>
 <tile id="1" type="ledge">
  <properties>
   <property name="one_way" type="bool" value="true"/>
  </properties>
 </tile>
 <tile id="2">
  <properties>
   <property name="solid" type="bool" value="false"/>
  </properties>
 </tile>
</tileset>
