<!DOCTYPE qgis PUBLIC 'http://mrcc.com/qgis.dtd' 'SYSTEM'>
<!-- towerpipe default style of the `towers` layer (tower footprints).
     Embedded in every towers.gpkg (table layer_styles); the `tower_points`
     layer gets the same labels, aliases and map tip with a marker symbol. -->
<qgis version="3.34.0" styleCategories="Symbology|Labeling|Fields|MapTips|Rendering" hasScaleBasedVisibilityFlag="0" minScale="100000000" maxScale="0" simplifyDrawingHints="0" labelsEnabled="1">
  <renderer-v2 type="singleSymbol" symbollevels="0" enableorderby="0" forceraster="0" referencescale="-1">
    <symbols>
      <symbol type="fill" name="0" alpha="1" clip_to_extent="1" force_rhr="0" frame_rate="10" is_animated="0">
        <data_defined_properties>
          <Option type="Map">
            <Option name="name" type="QString" value=""/>
            <Option name="properties"/>
            <Option name="type" type="QString" value="collection"/>
          </Option>
        </data_defined_properties>
        <layer class="SimpleFill" enabled="1" locked="0" pass="0">
          <Option type="Map">
            <Option name="border_width_map_unit_scale" type="QString" value="3x:0,0,0,0,0,0"/>
            <Option name="color" type="QString" value="227,26,28,80"/>
            <Option name="joinstyle" type="QString" value="miter"/>
            <Option name="offset" type="QString" value="0,0"/>
            <Option name="offset_unit" type="QString" value="MM"/>
            <Option name="outline_color" type="QString" value="165,15,21,255"/>
            <Option name="outline_style" type="QString" value="solid"/>
            <Option name="outline_width" type="QString" value="0.6"/>
            <Option name="outline_width_unit" type="QString" value="MM"/>
            <Option name="style" type="QString" value="solid"/>
          </Option>
        </layer>
      </symbol>
    </symbols>
    <rotation/>
    <sizescale/>
  </renderer-v2>
  <labeling type="simple">
    <settings calloutType="simple">
      <text-style fieldName="concat(&quot;tower_id&quot;, '\n', format_number(&quot;height_m&quot;, 1), ' m')" isExpression="1" fontFamily="Sans Serif" fontSize="8" fontSizeUnit="Point" fontWeight="50" fontItalic="0" textColor="40,40,40,255" textOpacity="1" namedStyle="Regular" multilineHeight="1" allowHtml="0" capitalization="0" blendMode="0" previewBkgrdColor="255,255,255,255">
        <text-buffer bufferDraw="1" bufferSize="0.8" bufferSizeUnits="MM" bufferColor="255,255,255,255" bufferOpacity="0.8" bufferNoFill="1" bufferJoinStyle="128" bufferBlendMode="0"/>
      </text-style>
      <text-format wrapChar="" multilineAlign="1" autoWrapLength="0" useMaxLineLengthForAutoWrap="1" addDirectionSymbol="0" formatNumbers="0" decimals="1" plussign="0"/>
      <placement placement="1" offsetType="0" dist="1.5" distUnits="MM" quadOffset="2" priority="5" fitInPolygonOnly="0"/>
      <rendering scaleVisibility="1" scaleMin="25000" scaleMax="1" obstacle="1" obstacleType="1" displayAll="0" upsidedownLabels="0" limitNumLabels="0" maxNumLabels="2000" minFeatureSize="0" fontLimitPixelSize="0" zIndex="0" labelPerPart="0" mergeLines="0" drawLabels="1"/>
    </settings>
  </labeling>
  <aliases>
    <alias field="fid" index="0" name=""/>
    <alias field="tower_id" index="1" name="Tower id"/>
    <alias field="zone" index="2" name="Zone"/>
    <alias field="block" index="3" name="Owning block"/>
    <alias field="blocks" index="4" name="Blocks touched"/>
    <alias field="centroid_x" index="5" name="Centroid X (m)"/>
    <alias field="centroid_y" index="6" name="Centroid Y (m)"/>
    <alias field="height_m" index="7" name="Height above ground (m)"/>
    <alias field="base_z" index="8" name="Base elevation (m)"/>
    <alias field="top_z" index="9" name="Top elevation (m)"/>
    <alias field="footprint_area_m2" index="10" name="Footprint area (m²)"/>
    <alias field="footprint_width_m" index="11" name="Footprint width (m)"/>
    <alias field="footprint_length_m" index="12" name="Footprint length (m)"/>
    <alias field="edge_distance_m" index="13" name="Distance to block edge (m)"/>
    <alias field="n_points" index="14" name="Points"/>
    <alias field="prob_mean" index="15" name="Mean probability"/>
    <alias field="prob_max" index="16" name="Max probability"/>
    <alias field="wire_support" index="17" name="Conductor support (0-1)"/>
    <alias field="source_files" index="18" name="Source files"/>
    <alias field="model_name" index="19" name="Model"/>
    <alias field="model_version" index="20" name="Model version"/>
    <alias field="processed_at" index="21" name="Processed at (UTC)"/>
  </aliases>
  <mapTip enabled="1">&lt;b>[% "tower_id" %]&lt;/b>&lt;br>height [% format_number("height_m", 1) %] m, base [% format_number("base_z", 1) %] m&lt;br>[% "n_points" %] points, mean probability [% format_number("prob_mean", 2) %], conductor support [% format_number("wire_support", 2) %]&lt;br>block [% "block" %] ([% "blocks" %])</mapTip>
  <previewExpression>"tower_id"</previewExpression>
  <layerGeometryType>2</layerGeometryType>
</qgis>
